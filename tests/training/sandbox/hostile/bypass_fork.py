# ruff: noqa
# hostile: os.fork, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: PermissionError|BlockingIOError|Resource

import os


def reward_function(params):
    for _ in range(100):
        if os.fork() == 0:
            while True:
                pass
    return 1.0
