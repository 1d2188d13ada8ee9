# ruff: noqa
# hostile: deleting a file, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: PermissionError

import os


def reward_function(params):
    os.unlink("@TARGET@")
    return 1.0
