# ruff: noqa
# hostile: match mapping pattern with a dunder key
# mode: guarded
# expect: SYNTAX_ERROR
# match: mapping pattern


def reward_function(params):
    match {"__builtins__": 1}:
        case {"__builtins__": b}:
            print(b)
    return 1.0
