# ruff: noqa
# hostile: sleeping past the limit, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: took longer than

import time


def reward_function(params):
    time.sleep(3600)
    return 1.0
