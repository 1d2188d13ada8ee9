# ruff: noqa
# hostile: setting the system clock, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: clock_settime refused

import ctypes
import os

libc = ctypes.CDLL(None, use_errno=True)
libc.syscall.restype = ctypes.c_long


def refused(what, rc):
    if rc == -1:
        raise OSError(f"{what} refused: {os.strerror(ctypes.get_errno())}")


class Timespec(ctypes.Structure):
    _fields_ = [("sec", ctypes.c_long), ("nsec", ctypes.c_long)]


def reward_function(params):
    refused("clock_settime", libc.clock_settime(0, ctypes.byref(Timespec(0, 0))))
    return 1.0
