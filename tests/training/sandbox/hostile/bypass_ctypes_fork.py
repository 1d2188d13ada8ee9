# ruff: noqa
# hostile: fork through ctypes, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: fork refused

import ctypes
import os


def reward_function(params):
    pid = ctypes.CDLL(None).fork()
    if pid == 0:
        os._exit(0)
    if pid < 0:
        raise OSError("fork refused")
    return 1.0
