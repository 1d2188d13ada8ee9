# ruff: noqa
# hostile: returning a list
# mode: guarded
# expect: TEST_FAILURE
# match: returned an object of type list


def reward_function(params):
    return [1.0]
