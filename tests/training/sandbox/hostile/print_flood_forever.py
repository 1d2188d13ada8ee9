# ruff: noqa
# hostile: an endless flood of output
# mode: guarded
# expect: TEST_FAILURE
# match: took longer than


def reward_function(params):
    while True:
        print("x" * 1000)
