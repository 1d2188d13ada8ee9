# ruff: noqa
# hostile: generator frame walk to the caller's globals
# mode: guarded
# expect: SYNTAX_ERROR
# match: gi_frame|f_back|f_globals


def reward_function(params):
    g = (i for i in [1])
    caller = g.gi_frame.f_back.f_back
    caller.f_globals["builtins"].open("@CANARY@", "w")
    return 1.0
