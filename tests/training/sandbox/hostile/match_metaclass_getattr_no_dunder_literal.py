# ruff: noqa
# hostile: match class pattern whose metaclass __getattr__ builds __match_args__ at run time ("_" * 2 + "self" + "_" * 2), no dunder string literal anywhere
# mode: guarded
# expect: SYNTAX_ERROR
# match: may not derive from 'type'
# line: 11

U = "_" * 2


class AcceptAll(type):
    def __instancecheck__(cls, obj):
        return True

    def __getattr__(cls, name):
        return cls.names


class Self(metaclass=AcceptAll):
    names = (U + "self" + U,)


class Import(metaclass=AcceptAll):
    names = (U + "import" + U,)


def reward_function(params):
    match len:
        case Self(real_builtins):
            match real_builtins:
                case Import(imp):
                    return float(len(imp("os").listdir("/")))
    return 1.0
