# ruff: noqa
# hostile: reading the parent's environment from /proc, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: PermissionError

import os


def reward_function(params):
    data = open(f"/proc/{os.getppid()}/environ", "rb").read()
    raise ValueError(data)
