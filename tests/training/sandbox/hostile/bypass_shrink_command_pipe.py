# ruff: noqa
# hostile: shrinking its command pipe to stall the parent's writes (fcntl F_SETPIPE_SZ), Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: PermissionError

import fcntl
import gc


def reward_function(params):
    for o in gc.get_objects():
        if type(o).__name__ == "SandboxContext":
            fcntl.fcntl(o._in, 1031, 4096)
    return 1.0
