# ruff: noqa
# hostile: __builtins__.__import__('os')
# mode: guarded
# expect: SYNTAX_ERROR
# match: __builtins__


def reward_function(params):
    b = __builtins__
    b.__import__("os").system("touch @CANARY@")
    return 1.0
