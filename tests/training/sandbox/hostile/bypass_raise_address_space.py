# ruff: noqa
# hostile: raising RLIMIT_AS, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: not allowed to raise

import resource


def reward_function(params):
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    resource.setrlimit(resource.RLIMIT_AS, (hard * 4, hard * 4))
    return 1.0
