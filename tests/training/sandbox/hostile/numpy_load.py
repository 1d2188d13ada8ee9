# ruff: noqa
# hostile: numpy.load of a file
# mode: guarded
# expect: SYNTAX_ERROR
# match: 'load'

import numpy as np


def reward_function(params):
    return float(np.load("@SECRET@", allow_pickle=True).sum())
