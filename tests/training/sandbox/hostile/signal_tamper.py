# ruff: noqa
# hostile: tampering with signals
# mode: guarded
# expect: IMPORT_ERROR
# match: signal

import signal


def reward_function(params):
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    signal.signal(signal.SIGALRM, signal.SIG_IGN)
    while True:
        pass
