# ruff: noqa
# hostile: an endless CPU loop
# mode: guarded
# expect: TEST_FAILURE
# match: took longer than


def reward_function(params):
    while True:
        pass
