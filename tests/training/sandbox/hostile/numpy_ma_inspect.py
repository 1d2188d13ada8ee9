# ruff: noqa
# hostile: the inspect module through numpy.ma.core
# mode: guarded
# expect: TEST_FAILURE
# match: module 'inspect'

import numpy as np


def reward_function(params):
    inspect = np.ma.core.inspect
    return float(len(inspect.stack()))
