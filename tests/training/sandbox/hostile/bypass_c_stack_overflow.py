# ruff: noqa
# hostile: recursion past the C stack after raising the limit, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: RecursionError|MemoryError|segmentation|took longer than|sandbox was stopped
# slow: yes

import sys


def dive(n):
    return dive(n + 1) + 1


def reward_function(params):
    sys.setrecursionlimit(10**8)
    return float(dive(0))
