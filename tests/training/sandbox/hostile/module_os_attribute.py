# ruff: noqa
# hostile: reaching os through a module attribute
# mode: guarded
# expect: SYNTAX_ERROR
# match: 'os'

import numpy as np


def reward_function(params):
    np.lib.format.os.system("touch @CANARY@")
    return 1.0
