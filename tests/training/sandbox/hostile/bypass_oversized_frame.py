# ruff: noqa
# hostile: announcing a 4 GB frame on its channel, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: sent malformed data

import gc
import os


def reward_function(params):
    for o in gc.get_objects():
        if type(o).__name__ == "SandboxContext":
            os.write(o._out, b"\xff\xff\xff\xf0")
    return 1.0
