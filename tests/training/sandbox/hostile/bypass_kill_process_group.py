# ruff: noqa
# hostile: signalling its whole process group, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: PermissionError

import os
import signal


def reward_function(params):
    os.kill(0, signal.SIGTERM)
    return 1.0
