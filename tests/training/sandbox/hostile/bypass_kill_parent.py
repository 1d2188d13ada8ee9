# ruff: noqa
# hostile: killing the parent, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: PermissionError

import os
import signal


def reward_function(params):
    os.kill(os.getppid(), signal.SIGKILL)
    return 1.0
