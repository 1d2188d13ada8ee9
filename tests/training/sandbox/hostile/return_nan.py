# ruff: noqa
# hostile: returning NaN
# mode: guarded
# expect: TEST_FAILURE
# match: returned nan at step 1


def reward_function(params):
    return float("nan")
