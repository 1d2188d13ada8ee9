# ruff: noqa
# hostile: numpy.save, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: PermissionError

import numpy as np


def reward_function(params):
    np.save("@CANARY@", np.zeros(3))
    return 1.0
