# ruff: noqa
# hostile: io_uring, which bypasses seccomp, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: io_uring_setup refused

import ctypes
import os

libc = ctypes.CDLL(None, use_errno=True)
libc.syscall.restype = ctypes.c_long


def refused(what, rc):
    if rc == -1:
        raise OSError(f"{what} refused: {os.strerror(ctypes.get_errno())}")


def reward_function(params):
    params_buf = ctypes.create_string_buffer(120)
    refused("io_uring_setup", libc.syscall(425, 8, params_buf))
    return 1.0
