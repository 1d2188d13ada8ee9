# ruff: noqa
# hostile: a float subclass with a hostile __float__
# mode: guarded
# expect: TEST_FAILURE
# match: returned an object of type Evil


class Evil(float):
    def __float__(self):
        while True:
            pass


def reward_function(params):
    return Evil(1.0)
