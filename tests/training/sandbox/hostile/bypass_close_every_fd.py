# ruff: noqa
# hostile: closing every descriptor, the channel included, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: sandbox was stopped

import os


def reward_function(params):
    os.closerange(0, 4096)
    return 1.0
