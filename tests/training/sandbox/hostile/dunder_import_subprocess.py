# ruff: noqa
# hostile: __import__('subprocess') through a variable
# mode: guarded
# expect: IMPORT_ERROR
# match: __import__

imp = __import__


def reward_function(params):
    imp("subprocess").run(["touch", "@CANARY@"])
    return 1.0
