# ruff: noqa
# hostile: format template assembled at run time, reached with getattr
# mode: guarded
# expect: TEST_FAILURE
# match: literal only


def reward_function(params):
    template = "{0." + "__class__}"
    return getattr(template, "format")(params)
