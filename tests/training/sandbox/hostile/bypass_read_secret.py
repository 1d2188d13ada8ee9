# ruff: noqa
# hostile: reading a file outside the allowed paths, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: PermissionError|FileNotFoundError


def reward_function(params):
    return float(len(open("@SECRET@").read()))
