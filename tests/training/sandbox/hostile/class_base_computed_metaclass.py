# ruff: noqa
# hostile: a class deriving from a metaclass computed at run time (bases unpacked from a list), with no special method in the class
# mode: guarded
# expect: TEST_FAILURE
# match: may not derive from 'type'
# line: 12


def reward_function(params):
    bases = [type(type(params))]

    class Meta(*bases):
        pass

    return 1.0
