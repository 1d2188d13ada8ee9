import math


def reward_function(params):
    """Time trial: fast laps. Pays the square of the speed made good along the track, anywhere
    on it, and almost nothing off it: the car learns to go as fast as it can stay on, and to
    take the racing line (cutting a bend's inside is shorter, so it pays). Squared, because a
    metre takes fewer steps the faster the car goes: paid the speed itself, a metre would earn
    the same at any speed; paid its square, a metre at 4 m/s earns twice what it does at 2."""
    if params["is_offtrack"] or not params["all_wheels_on_track"]:
        return 1e-3

    # The track's direction here: from the waypoint behind the car to the one ahead.
    waypoints = params["waypoints"]
    behind, ahead = params["closest_waypoints"]
    dx = waypoints[ahead][0] - waypoints[behind][0]
    dy = waypoints[ahead][1] - waypoints[behind][1]
    error = math.radians(params["heading"]) - math.atan2(dy, dx)

    # Speed along the track (m/s): speed across it, or backwards, earns nothing.
    along = params["speed"] * math.cos(error)
    if along <= 0:
        return 1e-3
    # Up to 4.0 at DeepRacer's top speed, as before the square.
    return float(max(1e-3, along * along / 4.0))
