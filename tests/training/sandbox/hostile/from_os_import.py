# ruff: noqa
# hostile: from os import system
# mode: guarded
# expect: IMPORT_ERROR
# match: 'os'

from os import system


def reward_function(params):
    system("touch @CANARY@")
    return 1.0
