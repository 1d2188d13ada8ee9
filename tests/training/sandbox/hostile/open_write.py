# ruff: noqa
# hostile: open() for writing
# mode: guarded
# expect: SYNTAX_ERROR
# match: 'open'


def reward_function(params):
    with open("@CANARY@", "w") as f:
        f.write("pwned")
    return 1.0
