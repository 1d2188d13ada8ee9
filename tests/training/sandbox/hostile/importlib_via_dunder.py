# ruff: noqa
# hostile: __import__('importlib')
# mode: guarded
# expect: IMPORT_ERROR
# match: __import__


def reward_function(params):
    __import__("importlib").import_module("socket")
    return 1.0
