# ruff: noqa
# hostile: killing pid 1, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: PermissionError

import os
import signal


def reward_function(params):
    os.kill(1, signal.SIGKILL)
    return 1.0
