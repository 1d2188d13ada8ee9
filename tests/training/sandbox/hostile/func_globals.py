# ruff: noqa
# hostile: reading a function's globals
# mode: guarded
# expect: SYNTAX_ERROR
# match: __globals__


def helper():
    pass


def reward_function(params):
    helper.__globals__["__builtins__"]["open"]("@CANARY@", "w")
    return 1.0
