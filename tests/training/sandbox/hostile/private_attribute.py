# ruff: noqa
# hostile: random._os
# mode: guarded
# expect: SYNTAX_ERROR
# match: _os

import random


def reward_function(params):
    random._os.system("touch @CANARY@")
    return 1.0
