# ruff: noqa
# hostile: one gigantic line of output, then NaN
# mode: guarded
# expect: TEST_FAILURE
# match: nan


def reward_function(params):
    print("y" * 50_000_000)
    return float("nan")
