# ruff: noqa
# hostile: walking every numpy attribute for a way out
# mode: guarded
# expect: TEST_FAILURE
# match: not allowed

import numpy as np


def reward_function(params):
    for name in dir(np):
        getattr(np, name)
    return 1.0
