# ruff: noqa
# hostile: an endless loop at module level
# mode: guarded
# expect: TEST_FAILURE
# match: loading the module took longer than

while True:
    pass


def reward_function(params):
    return 1.0
