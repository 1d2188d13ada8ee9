# ruff: noqa
# hostile: match class pattern reading __class__
# mode: guarded
# expect: SYNTAX_ERROR
# match: class pattern


def reward_function(params):
    match params:
        case object(__class__=cls):
            print(cls)
    return 1.0
