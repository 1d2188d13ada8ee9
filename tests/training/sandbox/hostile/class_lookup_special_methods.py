# ruff: noqa
# hostile: special methods that change how Python looks names up (__getattr__, __init_subclass__, __class_getitem__) in an ordinary class
# mode: guarded
# expect: SYNTAX_ERROR
# match: defining '__getattr__' is not allowed
# line: 10


class Anything:
    def __getattr__(self, name):
        return 1.0

    def __init_subclass__(cls, **kwargs):
        pass

    def __class_getitem__(cls, item):
        return cls


def reward_function(params):
    return Anything().progress
