# ruff: noqa
# hostile: reading the parent's environment from /proc, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: PermissionError

import os


def reward_function(params):
    # /proc is the host's: pid 1 there is the host's init, whose environment a parent shares;
    # getppid() is 0 inside the sandbox's own PID namespace.
    for pid in (1, os.getppid()):
        data = open(f"/proc/{pid}/environ", "rb").read()
        raise ValueError(data)
