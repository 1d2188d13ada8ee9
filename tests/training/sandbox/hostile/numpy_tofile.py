# ruff: noqa
# hostile: ndarray.tofile writes a file
# mode: guarded
# expect: SYNTAX_ERROR
# match: tofile

import numpy as np


def reward_function(params):
    np.zeros(3).tofile("@CANARY@")
    return 1.0
