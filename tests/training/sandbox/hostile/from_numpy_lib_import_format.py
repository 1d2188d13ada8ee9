# ruff: noqa
# hostile: from numpy.lib import format
# mode: guarded
# expect: IMPORT_ERROR
# match: numpy.lib.format

from numpy.lib import format


def reward_function(params):
    return 1.0
