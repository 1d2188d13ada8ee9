# ruff: noqa
# hostile: type renamed (t = type) so no call spells type(name, bases, dict), then a class made at run time
# mode: guarded
# expect: TEST_FAILURE
# match: three arguments
# line: 11


def reward_function(params):
    t = [type][0]
    Spy = t("Spy", (), {})
    return 1.0
