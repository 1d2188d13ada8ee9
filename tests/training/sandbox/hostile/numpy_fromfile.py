# ruff: noqa
# hostile: numpy.fromfile
# mode: guarded
# expect: SYNTAX_ERROR
# match: fromfile

import numpy as np


def reward_function(params):
    return float(np.fromfile("@SECRET@", dtype=np.uint8)[0])
