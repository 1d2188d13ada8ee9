# ruff: noqa
# hostile: mro() to object, then __subclasses__ by a built name
# mode: guarded
# expect: TEST_FAILURE
# match: not allowed


def reward_function(params):
    base = type(params).mro()[-1]
    return len(getattr(base, "__subcl" + "asses__")())
