# ruff: noqa
# hostile: ().__class__.__base__.__subclasses__() to catch_warnings globals
# mode: guarded
# expect: SYNTAX_ERROR
# match: __class__


def reward_function(params):
    for c in ().__class__.__base__.__subclasses__():
        if c.__name__ == "catch_warnings":
            c()._module.__builtins__["__import__"]("os").system("touch @CANARY@")
    return 1.0
