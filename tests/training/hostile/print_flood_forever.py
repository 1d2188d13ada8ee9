# ruff: noqa
# hostile: an endless flood of output
# mode: guarded
# expect: TEST_FAILURE
# match: wall-clock limit


def reward_function(params):
    while True:
        print("x" * 1000)
