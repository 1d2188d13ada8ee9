# ruff: noqa
# hostile: importing importlib
# mode: guarded
# expect: IMPORT_ERROR
# match: importlib

import importlib


def reward_function(params):
    importlib.import_module("os").system("touch @CANARY@")
    return 1.0
