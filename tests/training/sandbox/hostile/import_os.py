# ruff: noqa
# hostile: importing os directly
# mode: guarded
# expect: IMPORT_ERROR
# match: 'os'

import os


def reward_function(params):
    os.system("touch @CANARY@")
    return 1.0
