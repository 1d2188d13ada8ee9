# ruff: noqa
# hostile: import pickle
# mode: guarded
# expect: IMPORT_ERROR
# match: 'pickle'

import pickle


def reward_function(params):
    return pickle.loads(b"")
