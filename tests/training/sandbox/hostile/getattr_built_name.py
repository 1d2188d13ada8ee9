# ruff: noqa
# hostile: getattr with a dunder name built at run time
# mode: guarded
# expect: TEST_FAILURE
# match: not allowed


def reward_function(params):
    return getattr(params, "__cl" + "ass__")
