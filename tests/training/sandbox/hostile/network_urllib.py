# ruff: noqa
# hostile: network connection through urllib
# mode: guarded
# expect: IMPORT_ERROR
# match: urllib

import urllib.request


def reward_function(params):
    urllib.request.urlopen("http://127.0.0.1:@PORT@/")
    return 1.0
