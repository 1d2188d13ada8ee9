# ruff: noqa
# hostile: ignoring signals then looping, Python guards off
# mode: bypass
# expect: TEST_FAILURE
# match: took longer than

import signal


def reward_function(params):
    for s in (signal.SIGTERM, signal.SIGINT, signal.SIGALRM, signal.SIGXCPU):
        signal.signal(s, signal.SIG_IGN)
    while True:
        pass
