# ruff: noqa
# hostile: forging a reward message on its own channel, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: sent malformed data

import gc


def reward_function(params):
    for o in gc.get_objects():
        if type(o).__name__ == "SandboxContext":
            o.send({"i": 10**9, "value": float("nan")})
    return 1.0
