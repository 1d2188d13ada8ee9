# ruff: noqa
# hostile: unsharing namespaces to escape, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: unshare refused

import ctypes


def reward_function(params):
    if ctypes.CDLL(None).unshare(0x10000000 | 0x00020000) != 0:
        raise OSError("unshare refused")
    return 1.0
