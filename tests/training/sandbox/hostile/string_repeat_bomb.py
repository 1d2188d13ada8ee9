# ruff: noqa
# hostile: a 1 TB string
# mode: guarded
# expect: TEST_FAILURE
# match: MemoryError|OverflowError


def reward_function(params):
    s = "x" * (1 << 40)
    return 1.0
