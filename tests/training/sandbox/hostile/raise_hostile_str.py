# ruff: noqa
# hostile: an exception whose str() never returns
# mode: guarded
# expect: TEST_FAILURE
# match: took longer than


class Boom(Exception):
    def __str__(self):
        while True:
            pass


def reward_function(params):
    raise Boom()
