# ruff: noqa
# hostile: an endless CPU loop
# mode: guarded
# expect: TEST_FAILURE
# match: wall-clock limit


def reward_function(params):
    while True:
        pass
