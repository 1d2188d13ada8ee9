# ruff: noqa
# hostile: getattr(module, 'o' + 's')
# mode: guarded
# expect: TEST_FAILURE
# match: not allowed

import random


def reward_function(params):
    getattr(getattr(random, "_o" + "s"), "sys" + "tem")("touch @CANARY@")
    return 1.0
