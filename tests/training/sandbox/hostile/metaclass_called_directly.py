# ruff: noqa
# hostile: a metaclass (derived from type(int), not the name type) called directly, M("C", (), namespace), with its special methods named at run time
# mode: guarded
# expect: SYNTAX_ERROR
# match: may not derive from 'type'
# line: 10
U = "_" * 2


class Meta(type(int)):
    pass


def reward_function(params):
    accept = Meta("Accept", (), {U + "instancecheck" + U: lambda c, o: True})
    cls = Meta("C", (accept,), {U + "match_args" + U: (U + "self" + U,)})
    return 1.0
