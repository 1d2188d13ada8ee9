# ruff: noqa
# hostile: raising KeyboardInterrupt
# mode: guarded
# expect: TEST_FAILURE
# match: KeyboardInterrupt


def reward_function(params):
    raise KeyboardInterrupt
