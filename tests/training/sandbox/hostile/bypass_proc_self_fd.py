# ruff: noqa
# hostile: listing /proc/self/fd to find the channel, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: PermissionError

import os


def reward_function(params):
    return float(len(os.listdir("/proc/self/fd")))
