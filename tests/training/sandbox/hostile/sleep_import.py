# ruff: noqa
# hostile: sleeping with time.sleep
# mode: guarded
# expect: IMPORT_ERROR
# match: 'time'

import time


def reward_function(params):
    time.sleep(3600)
    return 1.0
