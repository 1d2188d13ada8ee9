# ruff: noqa
# hostile: memfd_create to stage a program, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: PermissionError

import os


def reward_function(params):
    fd = os.memfd_create("payload")
    return 1.0
