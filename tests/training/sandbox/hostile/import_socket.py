# ruff: noqa
# hostile: importing socket
# mode: guarded
# expect: IMPORT_ERROR
# match: 'socket'

import socket


def reward_function(params):
    socket.create_connection(("127.0.0.1", int("@PORT@")))
    return 1.0
