# ruff: noqa
# hostile: writing to fd 1 forever, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: took longer than

import os


def reward_function(params):
    while True:
        os.write(1, b"x" * 65536)
