# ruff: noqa
# hostile: the threading module through shapely.errors
# mode: guarded
# expect: TEST_FAILURE
# match: module 'threading'

import shapely.errors


def reward_function(params):
    shapely.errors.threading.Thread(target=print).start()
    return 1.0
