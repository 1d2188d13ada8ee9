# ruff: noqa
# hostile: a UDP datagram with a secret, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: PermissionError

import socket


def reward_function(params):
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.sendto(b"exfil", ("127.0.0.1", int("@PORT@")))
    return 1.0
