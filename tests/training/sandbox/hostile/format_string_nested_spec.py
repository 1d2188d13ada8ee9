# ruff: noqa
# hostile: format-string field hidden in a nested format spec
# mode: guarded
# expect: SYNTAX_ERROR
# match: __globals__


def reward_function(params):
    return float("{0:{1.__globals__}}".format(1, reward_function))
