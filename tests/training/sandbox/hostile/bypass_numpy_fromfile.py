# ruff: noqa
# hostile: numpy.fromfile of a secret, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: PermissionError|FileNotFoundError

import numpy as np


def reward_function(params):
    return float(np.fromfile("@SECRET@", dtype=np.uint8).sum())
