# ruff: noqa
# hostile: numpy.lib.format reached with getattr at run time
# mode: guarded
# expect: TEST_FAILURE
# match: numpy.lib.format

import numpy as np


def reward_function(params):
    fmt = getattr(np.lib, "for" + "mat")
    return 1.0
