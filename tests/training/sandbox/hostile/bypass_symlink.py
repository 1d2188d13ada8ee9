# ruff: noqa
# hostile: planting a symlink, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: PermissionError

import os


def reward_function(params):
    os.symlink("@TARGET@", "@CANARY@")
    return 1.0
