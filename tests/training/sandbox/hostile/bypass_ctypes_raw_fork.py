# ruff: noqa
# hostile: raw fork syscall through ctypes, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: fork refused

import ctypes
import os

libc = ctypes.CDLL(None, use_errno=True)
libc.syscall.restype = ctypes.c_long


def refused(what, rc):
    if rc == -1:
        raise OSError(f"{what} refused: {os.strerror(ctypes.get_errno())}")


def reward_function(params):
    # clone(SIGCHLD) is a fork on both x86_64 (56) and aarch64 (220), bypassing os.fork.
    nr = {"aarch64": 220}.get(os.uname().machine, 56)
    rc = libc.syscall(nr, 17, 0, 0, 0, 0)
    if rc == 0:
        os._exit(0)
    refused("fork", rc)
    return 1.0
