import math


def reward_function(params):
    """Time trial: fast laps. Pays the speed made good along the track, more near the centre
    line, and almost nothing off it: the car learns to go as fast as it can stay on."""
    if params["is_offtrack"] or not params["all_wheels_on_track"]:
        return 1e-3

    # The track's direction here: from the waypoint behind the car to the one ahead.
    waypoints = params["waypoints"]
    behind, ahead = params["closest_waypoints"]
    dx = waypoints[ahead][0] - waypoints[behind][0]
    dy = waypoints[ahead][1] - waypoints[behind][1]
    error = math.radians(params["heading"]) - math.atan2(dy, dx)

    # Speed along the track (m/s), weighed by closeness to the centre line (1 on it, 0.5 at
    # the border): speed across the track earns nothing.
    along = params["speed"] * math.cos(error)
    centre = 1.0 - params["distance_from_center"] / (params["track_width"] / 2)
    return float(max(1e-3, along * (0.5 + 0.5 * centre)))
