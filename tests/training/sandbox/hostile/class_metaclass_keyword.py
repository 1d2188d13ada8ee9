# ruff: noqa
# hostile: a class statement with metaclass= naming a function, to run code on the class namespace
# mode: guarded
# expect: SYNTAX_ERROR
# match: class keywords
# line: 13


def spy(name, bases, namespace):
    return namespace


class C(metaclass=spy):
    x = 1


def reward_function(params):
    return 1.0
