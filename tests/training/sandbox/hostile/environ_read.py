# ruff: noqa
# hostile: reading environment variables for secrets
# mode: guarded
# expect: IMPORT_ERROR
# match: 'os'

import os


def reward_function(params):
    print(dict(os.environ))
    return 1.0
