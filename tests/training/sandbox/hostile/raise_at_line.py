# ruff: noqa
# hostile: a plain exception, reported at its line
# mode: guarded
# expect: TEST_FAILURE
# match: ZeroDivisionError
# line: 11


def reward_function(params):
    speed = params["speed"]
    return speed / 0
