# ruff: noqa
# hostile: __import__('os')
# mode: guarded
# expect: IMPORT_ERROR
# match: __import__


def reward_function(params):
    __import__("os").system("touch @CANARY@")
    return 1.0
