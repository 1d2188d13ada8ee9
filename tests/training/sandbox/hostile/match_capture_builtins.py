# ruff: noqa
# hostile: match capture pattern rebinding __builtins__
# mode: guarded
# expect: SYNTAX_ERROR
# match: __builtins__


def reward_function(params):
    match params:
        case __builtins__:
            pass
    return 1.0
