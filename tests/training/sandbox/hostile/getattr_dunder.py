# ruff: noqa
# hostile: getattr with built-up dunder names
# mode: guarded
# expect: TEST_FAILURE
# match: not allowed


def reward_function(params):
    cls = getattr((), "__cla" + "ss__")
    base = getattr(cls, "__ba" + "se__")
    getattr(base, "__subcl" + "asses__")()
    return 1.0
