"""A stand-in import child that never answers (for the deadline test): it writes its pid to
``$STALL_PID_FILE`` and sleeps."""

from __future__ import annotations

import os
import time
from pathlib import Path

if __name__ == "__main__":
    Path(os.environ["STALL_PID_FILE"]).write_text(str(os.getpid()))
    while True:
        time.sleep(60)
