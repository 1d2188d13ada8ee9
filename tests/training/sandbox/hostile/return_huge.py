# ruff: noqa
# hostile: returning a value over 1e5
# mode: guarded
# expect: TEST_FAILURE
# match: returned 1000000.0 at step 1


def reward_function(params):
    return 1e6
