# ruff: noqa
# hostile: exec of a fresh interpreter, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: PermissionError

import os
import sys


def reward_function(params):
    os.execv(sys.executable, [sys.executable, "-c", "open('@CANARY@', 'w')"])
