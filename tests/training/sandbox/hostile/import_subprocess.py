# ruff: noqa
# hostile: importing subprocess
# mode: guarded
# expect: IMPORT_ERROR
# match: 'subprocess'

import subprocess


def reward_function(params):
    subprocess.run(["touch", "@CANARY@"])
    return 1.0
