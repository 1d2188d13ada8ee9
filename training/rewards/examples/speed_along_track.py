import math


def reward_function(params):
    """Time trial: fast laps. Pays the speed made good along the track, anywhere on it, and
    almost nothing off it: the car learns to go as fast as it can stay on, and to take the
    racing line (cutting a bend's inside is shorter, so it pays)."""
    if params["is_offtrack"] or not params["all_wheels_on_track"]:
        return 1e-3

    # The track's direction here: from the waypoint behind the car to the one ahead.
    waypoints = params["waypoints"]
    behind, ahead = params["closest_waypoints"]
    dx = waypoints[ahead][0] - waypoints[behind][0]
    dy = waypoints[ahead][1] - waypoints[behind][1]
    error = math.radians(params["heading"]) - math.atan2(dy, dx)

    # Speed along the track (m/s): speed across it earns nothing.
    along = params["speed"] * math.cos(error)
    return float(max(1e-3, along))
