# ruff: noqa
# hostile: a TCP connection to the host, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: PermissionError|Network is unreachable|refused

import socket


def reward_function(params):
    socket.create_connection(("127.0.0.1", int("@PORT@")), timeout=0.5).sendall(b"pwned")
    return 1.0
