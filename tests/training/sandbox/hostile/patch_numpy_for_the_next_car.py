# ruff: noqa
# hostile: monkeypatching numpy
# mode: guarded
# expect: TEST_FAILURE
# match: cannot be changed

import numpy as np


def reward_function(params):
    np.sqrt = lambda x: 1e9
    return 1.0
