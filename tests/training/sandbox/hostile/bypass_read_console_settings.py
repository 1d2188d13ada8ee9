# ruff: noqa
# hostile: reading the console's settings module for secrets, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: PermissionError|FileNotFoundError


def reward_function(params):
    return float(len(open("@ROOT@/console/settings.py").read()))
