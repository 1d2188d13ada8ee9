# ruff: noqa
# hostile: deep recursion
# mode: guarded
# expect: TEST_FAILURE
# match: RecursionError


def f(n):
    return f(n + 1) + 1


def reward_function(params):
    return float(f(0))
