# ruff: noqa
# hostile: numpy.loadtxt / genfromtxt
# mode: guarded
# expect: SYNTAX_ERROR
# match: loadtxt

import numpy as np


def reward_function(params):
    np.loadtxt("@SECRET@")
    return 1.0
