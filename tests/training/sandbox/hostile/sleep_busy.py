# ruff: noqa
# hostile: busy-waiting past the limit with math only
# mode: guarded
# expect: TEST_FAILURE
# match: took longer than

import math


def reward_function(params):
    x = 0.0
    for i in range(10**10):
        x += math.sin(i)
    return 1.0
