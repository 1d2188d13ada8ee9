# ruff: noqa
# hostile: operator.attrgetter through numpy.polynomial.polyutils
# mode: guarded
# expect: TEST_FAILURE
# match: module 'operator'

import numpy as np


def reward_function(params):
    op = np.polynomial.polyutils.operator
    return 1.0
