# ruff: noqa
# hostile: returning -inf
# mode: guarded
# expect: TEST_FAILURE
# match: returned -inf


def reward_function(params):
    return -float("inf")
