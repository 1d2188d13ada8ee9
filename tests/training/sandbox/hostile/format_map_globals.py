# ruff: noqa
# hostile: format_map reaching a function's globals
# mode: guarded
# expect: SYNTAX_ERROR
# match: __globals__


def reward_function(params):
    "{f.__globals__[x]}".format_map({"f": reward_function})
    return 1.0
