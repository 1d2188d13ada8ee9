# ruff: noqa
# hostile: renicing every process of its user and pinning pid 2 (setpriority PRIO_USER, sched_setaffinity), Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: PermissionError|ProcessLookupError

import os


def reward_function(params):
    # Refused outright by seccomp (PRIO_USER is never the caller alone): the uid is one no
    # process uses, so a regression here renices nothing.
    os.setpriority(os.PRIO_USER, 54321, 19)
    os.sched_setaffinity(2, {0})
    return 1.0
