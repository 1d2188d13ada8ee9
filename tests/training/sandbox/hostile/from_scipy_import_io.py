# ruff: noqa
# hostile: from scipy import io
# mode: guarded
# expect: IMPORT_ERROR
# match: scipy.io

from scipy import io


def reward_function(params):
    io.loadmat("@SECRET@")
    return 1.0
