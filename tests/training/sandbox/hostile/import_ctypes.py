# ruff: noqa
# hostile: importing ctypes
# mode: guarded
# expect: IMPORT_ERROR
# match: 'ctypes'

import ctypes


def reward_function(params):
    ctypes.string_at(0)
    return 1.0
