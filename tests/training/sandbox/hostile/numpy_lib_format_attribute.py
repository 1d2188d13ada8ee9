# ruff: noqa
# hostile: numpy.lib.format reached as an attribute
# mode: guarded
# expect: SYNTAX_ERROR
# match: numpy.lib.format

import numpy as np


def reward_function(params):
    np.lib.format.write_array(None, np.zeros(1))
    return 1.0
