# ruff: noqa
# hostile: from numpy import save
# mode: guarded
# expect: IMPORT_ERROR
# match: save

from numpy import save


def reward_function(params):
    save("@CANARY@", [1])
    return 1.0
