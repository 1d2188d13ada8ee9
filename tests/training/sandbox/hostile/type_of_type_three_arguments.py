# ruff: noqa
# hostile: the real type reached as type(type(1)) and called with three arguments (import reached through __match_args__)
# mode: guarded
# expect: TEST_FAILURE
# match: three arguments
# line: 12
U = "_" * 2


def reward_function(params):
    make = type(type(1))
    Spy = make("Spy", (), {U + "match_args" + U: (U + "self" + U,)})
    match len:
        case Spy(real_builtins):
            return float(len(real_builtins))
    return 1.0
