# ruff: noqa
# hostile: stopping its heartbeat, then sleeping, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: took longer than

import gc
import time


def reward_function(params):
    for o in gc.get_objects():
        if type(o).__name__ == "RewardCallable":
            o._hb[1] = 0
    time.sleep(3600)
