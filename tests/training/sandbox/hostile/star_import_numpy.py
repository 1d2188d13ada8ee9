# ruff: noqa
# hostile: from numpy import * (brings load/save)
# mode: guarded
# expect: IMPORT_ERROR
# match: import \*

from numpy import *


def reward_function(params):
    return 1.0
