# ruff: noqa
# hostile: importing os inside the function
# mode: guarded
# expect: IMPORT_ERROR
# match: 'os'


def reward_function(params):
    import os

    os.system("touch @CANARY@")
    return 1.0
