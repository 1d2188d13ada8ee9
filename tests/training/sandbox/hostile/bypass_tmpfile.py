# ruff: noqa
# hostile: an anonymous O_TMPFILE file, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: PermissionError|IsADirectoryError|OSError

import os


def reward_function(params):
    fd = os.open(os.path.dirname("@CANARY@"), os.O_TMPFILE | os.O_WRONLY)
    return 1.0
