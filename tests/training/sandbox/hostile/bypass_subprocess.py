# ruff: noqa
# hostile: subprocess.run, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: PermissionError

import subprocess


def reward_function(params):
    subprocess.run(["/bin/sh", "-c", "touch @CANARY@"])
    return 1.0
