# ruff: noqa
# hostile: ().__class__.__mro__[1].__subclasses__() walk
# mode: guarded
# expect: SYNTAX_ERROR
# match: __class__


def reward_function(params):
    for cls in ().__class__.__mro__[1].__subclasses__():
        if cls.__name__ == "Popen":
            cls(["touch", "@CANARY@"])
    return 1.0
