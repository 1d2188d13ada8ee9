# ruff: noqa
# hostile: returning a string
# mode: guarded
# expect: TEST_FAILURE
# match: returned '1.0'


def reward_function(params):
    return "1.0"
