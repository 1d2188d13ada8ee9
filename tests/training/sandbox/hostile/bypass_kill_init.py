# ruff: noqa
# hostile: killing pid 1 and its neighbours, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: PermissionError|ProcessLookupError

import os
import signal


def reward_function(params):
    # In its own PID namespace the sandbox is pid 1 itself (the kernel ignores the signal
    # there); pid 2 would be the host's kthreadd, and names nothing here.
    if os.getpid() != 1:
        os.kill(1, signal.SIGKILL)
    os.kill(2, signal.SIGKILL)
    return 1.0
