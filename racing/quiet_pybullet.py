"""PyBullet without its banner.

Importing ``pybullet`` makes its C extension print ``pybullet build time: ...`` (on file
descriptor 1 or 2, depending on the build and on whether they are terminals), so every command,
``--help`` included, started with it. Here fds 1 and 2 point at /dev/null for the length of the
import (C's buffers flushed before they are put back); an import error is still raised as an
exception. Import ``pb`` and ``bullet_client`` from this module, never ``pybullet`` directly.
"""

from __future__ import annotations

import ctypes
import os
import sys


def _flush_c_stdio() -> None:
    try:
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError):
        pass


def _import_quietly():  # noqa: ANN202
    if "pybullet" in sys.modules:
        return sys.modules["pybullet"]
    saved: list[tuple[int, int]] = []
    try:
        for stream in (sys.stdout, sys.stderr):
            if stream is not None:
                stream.flush()
        devnull = os.open(os.devnull, os.O_WRONLY)
        try:
            for fd in (1, 2):
                saved.append((fd, os.dup(fd)))
                os.dup2(devnull, fd)
        finally:
            os.close(devnull)
    except (OSError, ValueError, AttributeError):
        pass  # no usable descriptors: import as is
    try:
        import pybullet

        _flush_c_stdio()
    finally:
        for fd, copy in saved:
            os.dup2(copy, fd)
            os.close(copy)
    return pybullet


pb = _import_quietly()

from pybullet_utils import bullet_client  # noqa: E402 - after pybullet, which it imports

__all__ = ["bullet_client", "pb"]
