# ruff: noqa
# hostile: a unix socket to Redis, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: PermissionError

import socket


def reward_function(params):
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.connect("@REDIS_SOCKET@")
    s.sendall(b"FLUSHALL\r\n")
    return 1.0
