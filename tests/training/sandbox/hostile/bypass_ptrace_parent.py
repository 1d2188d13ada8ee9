# ruff: noqa
# hostile: ptrace-attaching to the parent, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: ptrace refused

import ctypes
import os

libc = ctypes.CDLL(None, use_errno=True)
libc.syscall.restype = ctypes.c_long


def refused(what, rc):
    if rc == -1:
        raise OSError(f"{what} refused: {os.strerror(ctypes.get_errno())}")


def reward_function(params):
    refused("ptrace", libc.ptrace(16, os.getppid(), None, None))
    return 1.0
