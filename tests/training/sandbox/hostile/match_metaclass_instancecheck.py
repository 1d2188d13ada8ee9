# ruff: noqa
# hostile: match class pattern with a metaclass whose __instancecheck__ accepts anything and __match_args__ naming __self__, to reach the real builtins and __import__
# mode: guarded
# expect: SYNTAX_ERROR
# match: may not derive from 'type'
# line: 9


class AcceptAll(type):
    def __instancecheck__(cls, obj):
        return True


class Self(metaclass=AcceptAll):
    __match_args__ = ("__self__",)


class Import(metaclass=AcceptAll):
    __match_args__ = ("__import__",)


def reward_function(params):
    match len:
        case Self(real_builtins):
            match real_builtins:
                case Import(imp):
                    return float(len(imp("os").listdir("/")))
    return 1.0
