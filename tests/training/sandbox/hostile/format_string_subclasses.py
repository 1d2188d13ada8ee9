# ruff: noqa
# hostile: format-string attribute access to __subclasses__
# mode: guarded
# expect: SYNTAX_ERROR
# match: in a format string


def reward_function(params):
    return "{0.__class__.__base__.__subclasses__}".format(params)
