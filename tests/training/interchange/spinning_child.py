"""A stand-in import child that computes forever (for the CPU-time test) under the real
child's own limits (:func:`training.interchange.importchild.limit_self`)."""

from __future__ import annotations

import sys
from pathlib import Path

from training.interchange.importchild import limit_self

if __name__ == "__main__":
    limit_self(Path(sys.argv[1]))
    total = 0
    while True:
        total = (total + 1) % 1_000_003
