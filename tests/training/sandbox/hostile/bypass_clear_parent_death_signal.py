# ruff: noqa
# hostile: clearing the parent-death signal, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: prctl refused

import ctypes
import os

libc = ctypes.CDLL(None, use_errno=True)
libc.syscall.restype = ctypes.c_long


def refused(what, rc):
    if rc == -1:
        raise OSError(f"{what} refused: {os.strerror(ctypes.get_errno())}")


def reward_function(params):
    refused("prctl", libc.prctl(1, 0, 0, 0, 0))
    return 1.0
