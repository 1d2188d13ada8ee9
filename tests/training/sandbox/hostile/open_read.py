# ruff: noqa
# hostile: open() for reading
# mode: guarded
# expect: SYNTAX_ERROR
# match: 'open'


def reward_function(params):
    return float(len(open("@SECRET@").read()))
