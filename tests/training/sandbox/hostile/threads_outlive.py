# ruff: noqa
# hostile: a thread that outlives the call
# mode: guarded
# expect: IMPORT_ERROR
# match: threading

import threading


def reward_function(params):
    threading.Thread(target=lambda: [0 for _ in iter(int, 1)], daemon=False).start()
    return 1.0
