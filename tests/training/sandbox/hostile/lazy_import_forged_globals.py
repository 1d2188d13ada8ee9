# ruff: noqa
# hostile: the guard's __import__ (reached through __builtins__) called with numpy's own globals, as numpy's lazy imports call it, to get os
# mode: guarded
# expect: SYNTAX_ERROR
# match: __builtins__
# line: 12
import numpy as np


def reward_function(params):
    np.array([1.0, 2.0]).mean()  # numpy's own lazy import: served
    imp = reward_function.__builtins__["__import__"]
    library = np.isscalar.__globals__  # numpy._core.numeric's own globals
    got = [imp("os", library, library, [], 0), imp("numpy", library), imp("math")]
    try:
        imp("this", library, library, [], 0)  # never loaded: refused, not run
        return 0.0
    except ImportError:
        pass
    if all(module is None for module in got):
        return 1.0
    got[0].system("touch @CANARY@")
    return 0.0
