# ruff: noqa
# hostile: memory bomb: growing a string
# mode: guarded
# expect: TEST_FAILURE
# match: MemoryError


def reward_function(params):
    s = "x"
    while True:
        s = s * 100_000
