# ruff: noqa
# hostile: a lookup-changing special method added to a class after it was made, by setattr with a name built at run time
# mode: guarded
# expect: TEST_FAILURE
# match: not allowed
# line: 15
U = "_" * 2


class C:
    pass


def reward_function(params):
    setattr(C, U + "getattr" + U, lambda self, name: 1.0)
    return C().anything
