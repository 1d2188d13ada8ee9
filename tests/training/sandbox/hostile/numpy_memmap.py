# ruff: noqa
# hostile: numpy.memmap
# mode: guarded
# expect: SYNTAX_ERROR
# match: memmap

import numpy as np


def reward_function(params):
    m = np.memmap("@CANARY@", mode="w+", shape=(10,))
    return 1.0
