"""A sandbox target that stops reading its commands (tests/training/sandbox/
test_sandbox_host_unchanged.py): its command pipe shrunk to one page before lock-down (after
it, seccomp refuses F_SETPIPE_SZ), then it sleeps and never reads again."""

from __future__ import annotations

import fcntl
import sys
import time

F_SETPIPE_SZ = 1031


def shrink(args: object) -> None:
    """The prepare hook: the child's command pipe is argv[1] of its interpreter."""
    fcntl.fcntl(int(sys.argv[1]), F_SETPIPE_SZ, 4096)


def stall(ctx: object) -> None:
    time.sleep(3600)
