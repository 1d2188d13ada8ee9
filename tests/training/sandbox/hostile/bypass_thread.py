# ruff: noqa
# hostile: a thread that outlives the call, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: can't start new thread

import threading


def reward_function(params):
    threading.Thread(target=lambda: [0 for _ in iter(int, 1)]).start()
    return 1.0
