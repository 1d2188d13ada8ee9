# ruff: noqa
# hostile: numpy.ctypeslib reaches ctypes
# mode: guarded
# expect: SYNTAX_ERROR
# match: ctypeslib

import numpy as np


def reward_function(params):
    np.ctypeslib.ctypes.CDLL(None).system(b"touch @CANARY@")
    return 1.0
