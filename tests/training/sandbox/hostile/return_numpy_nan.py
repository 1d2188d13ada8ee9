# ruff: noqa
# hostile: returning numpy.float32('nan')
# mode: guarded
# expect: TEST_FAILURE
# match: returned np.float32\(nan\)|returned nan

import numpy as np


def reward_function(params):
    return np.float32("nan")
