# ruff: noqa
# hostile: raising its own memory limit, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: not allowed|Operation not permitted

import resource


def reward_function(params):
    resource.setrlimit(resource.RLIMIT_AS, (resource.RLIM_INFINITY, resource.RLIM_INFINITY))
    return 1.0
