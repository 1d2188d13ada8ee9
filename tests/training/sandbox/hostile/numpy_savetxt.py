# ruff: noqa
# hostile: numpy.savetxt / save
# mode: guarded
# expect: SYNTAX_ERROR
# match: savetxt

import numpy


def reward_function(params):
    numpy.savetxt("@CANARY@", numpy.zeros(3))
    return 1.0
