# ruff: noqa
# hostile: mutating params to break the caller
# mode: guarded
# expect: OK
# match:

FIRST = []


def reward_function(params):
    n = len(params["waypoints"])
    FIRST.append(n)
    if n != FIRST[0] or n < 3 or not isinstance(params["x"], float) or len(params) < 20:
        return float("nan")  # an earlier call's mutation leaked into this one
    params["waypoints"].clear()
    params["closest_waypoints"][0] = "broken"
    params["x"] = None
    params.clear()
    return 1.0
