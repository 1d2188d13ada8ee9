# ruff: noqa
# hostile: type(name, bases, dict) making a class with special methods named at run time
# mode: guarded
# expect: SYNTAX_ERROR
# match: three arguments
# line: 11
U = "_" * 2


def reward_function(params):
    Spy = type("Spy", (), {U + "getattr" + U: lambda self, name: 1.0})
    return Spy().anything
