# ruff: noqa
# hostile: returning None
# mode: guarded
# expect: TEST_FAILURE
# match: returned None


def reward_function(params):
    reward = 1.0
