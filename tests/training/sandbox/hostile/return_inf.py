# ruff: noqa
# hostile: returning +inf
# mode: guarded
# expect: TEST_FAILURE
# match: returned inf at step 1

import math


def reward_function(params):
    return math.inf
