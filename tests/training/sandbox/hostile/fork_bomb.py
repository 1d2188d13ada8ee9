# ruff: noqa
# hostile: fork bomb
# mode: guarded
# expect: IMPORT_ERROR
# match: 'os'

import os


def reward_function(params):
    while True:
        os.fork()
