# ruff: noqa
# hostile: a long computation inside one C call
# mode: guarded
# expect: TEST_FAILURE
# match: took longer than
# slow: yes

import math


def reward_function(params):
    return float(math.factorial(10**8) % 7)
