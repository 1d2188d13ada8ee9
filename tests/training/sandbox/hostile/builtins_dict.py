# ruff: noqa
# hostile: __builtins__['open']
# mode: guarded
# expect: SYNTAX_ERROR
# match: __builtins__


def reward_function(params):
    __builtins__["open"]("@CANARY@", "w").write("x")
    return 1.0
