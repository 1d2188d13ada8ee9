# ruff: noqa
# hostile: f-string reading a dunder attribute
# mode: guarded
# expect: SYNTAX_ERROR
# match: __class__


def reward_function(params):
    print(f"{params.__class__}")
    return 1.0
