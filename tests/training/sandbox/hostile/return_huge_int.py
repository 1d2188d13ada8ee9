# ruff: noqa
# hostile: returning an int too large for a float
# mode: guarded
# expect: TEST_FAILURE
# match: returned a number too large|returned 1000


def reward_function(params):
    return 10**400
