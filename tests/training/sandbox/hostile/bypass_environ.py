# ruff: noqa
# hostile: printing os.environ, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: ENVIRON

import os


def reward_function(params):
    raise ValueError("ENVIRON " + repr(dict(os.environ)))
