# ruff: noqa
# hostile: scipy.io.savemat / loadmat
# mode: guarded
# expect: IMPORT_ERROR
# match: scipy.io

import scipy.io


def reward_function(params):
    scipy.io.savemat("@CANARY@", {"a": 1})
    return 1.0
