# ruff: noqa
# hostile: network connection through http.client
# mode: guarded
# expect: IMPORT_ERROR
# match: http

import http.client


def reward_function(params):
    http.client.HTTPConnection("127.0.0.1", int("@PORT@")).request("GET", "/")
    return 1.0
