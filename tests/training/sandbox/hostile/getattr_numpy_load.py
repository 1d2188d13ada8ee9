# ruff: noqa
# hostile: getattr reaching np.load by a built name
# mode: guarded
# expect: TEST_FAILURE
# match: 'load' is not allowed

import numpy as np


def reward_function(params):
    load = getattr(np, "lo" + "ad")
    load("@SECRET@")
    return 1.0
