# ruff: noqa
# hostile: memory bomb: a huge list
# mode: guarded
# expect: TEST_FAILURE
# match: MemoryError


def reward_function(params):
    x = [0] * (10**10)
    return float(len(x))
