# ruff: noqa
# hostile: os._exit mid-call, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: exited unexpectedly

import os


def reward_function(params):
    os._exit(0)
