# ruff: noqa
# hostile: importing sys
# mode: guarded
# expect: IMPORT_ERROR
# match: 'sys'

import sys


def reward_function(params):
    sys.exit(0)
