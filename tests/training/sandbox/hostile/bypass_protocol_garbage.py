# ruff: noqa
# hostile: writing garbage to the result pipe, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: malformed|over the|unexpectedly|unknown

import os


def reward_function(params):
    for fd in range(3, 64):
        try:
            os.write(fd, b"\xff" * 64)
        except OSError:
            pass
    os._exit(0)
