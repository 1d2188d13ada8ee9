# ruff: noqa
# hostile: memory bomb: a huge numpy array
# mode: guarded
# expect: TEST_FAILURE
# match: MemoryError|Unable to allocate

import numpy as np


def reward_function(params):
    x = np.ones((200000, 200000))
    return float(x.sum())
