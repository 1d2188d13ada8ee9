# ruff: noqa
# hostile: exception traceback to the caller's frame
# mode: guarded
# expect: SYNTAX_ERROR
# match: __traceback__


def reward_function(params):
    try:
        1 / 0
    except ZeroDivisionError as e:
        frame = e.__traceback__.tb_frame.f_back
    return 1.0
