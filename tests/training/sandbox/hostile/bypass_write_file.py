# ruff: noqa
# hostile: open() for writing, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: PermissionError|Operation not permitted


def reward_function(params):
    with open("@CANARY@", "w") as f:
        f.write("pwned")
    return 1.0
