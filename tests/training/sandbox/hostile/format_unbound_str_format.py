# ruff: noqa
# hostile: str.format called unbound on a variable template
# mode: guarded
# expect: SYNTAX_ERROR
# match: string literal only


def reward_function(params):
    t = "{0.__cl" + "ass__}"
    return str.format(t, params)
