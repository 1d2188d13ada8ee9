# ruff: noqa
# hostile: eval / exec / compile
# mode: guarded
# expect: SYNTAX_ERROR
# match: 'eval'


def reward_function(params):
    eval("__import__('os').system('touch @CANARY@')")
    return 1.0
