# ruff: noqa
# hostile: raising SystemExit
# mode: guarded
# expect: TEST_FAILURE
# match: SystemExit


def reward_function(params):
    raise SystemExit(0)
