# ruff: noqa
# hostile: leaving its process group (setsid) to dodge killpg, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: PermissionError

import os


def reward_function(params):
    os.setsid()
    return 1.0
