# ruff: noqa
# hostile: writing /proc/self/mem, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: PermissionError

import os


def reward_function(params):
    fd = os.open("/proc/self/mem", os.O_RDWR)
    return 1.0
