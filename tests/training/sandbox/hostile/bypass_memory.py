# ruff: noqa
# hostile: allocating 8 GiB, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: MemoryError


def reward_function(params):
    x = bytearray(8 << 30)
    return float(len(x))
