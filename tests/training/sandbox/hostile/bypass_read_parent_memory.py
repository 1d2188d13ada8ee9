# ruff: noqa
# hostile: process_vm_readv on the parent, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: process_vm_readv refused

import ctypes
import os

libc = ctypes.CDLL(None, use_errno=True)
libc.syscall.restype = ctypes.c_long


def refused(what, rc):
    if rc == -1:
        raise OSError(f"{what} refused: {os.strerror(ctypes.get_errno())}")


class IoVec(ctypes.Structure):
    _fields_ = [("base", ctypes.c_void_p), ("len", ctypes.c_size_t)]


def reward_function(params):
    buf = ctypes.create_string_buffer(64)
    local = IoVec(ctypes.cast(buf, ctypes.c_void_p), 64)
    remote = IoVec(0x400000, 64)
    rc = libc.process_vm_readv(os.getppid(), ctypes.byref(local), 1, ctypes.byref(remote), 1, 0)
    refused("process_vm_readv", rc)
    return 1.0
