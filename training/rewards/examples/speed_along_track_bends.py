import math

LOOK_AHEAD_M = 1.5
"""How far ahead along the track (waypoint by waypoint) its direction is compared with here."""
BEND_DEG = 25.0
"""A change of direction bigger than this by LOOK_AHEAD_M ahead is a bend to ease off for."""
EASE_OFF_ABOVE = 3.0
"""Speeds above this (m/s) into a bend earn half."""


def reward_function(params):
    """Time trial: fast laps, easing off before bends. Pays the square of the speed made good
    along the track, anywhere on it, as the racing preset's reward does, and half of it for a
    speed above 3 m/s where the track's direction 1.5 m ahead differs from its direction here
    by more than 25 degrees. One camera frame does not show how fast the car goes, so a car
    that learns only from the far end of a bend keeps arriving too fast; this tells it at once.
    Uses DeepRacer's params only."""
    if params["is_offtrack"] or not params["all_wheels_on_track"]:
        return 1e-3

    # The track's direction here: from the waypoint behind the car to the one ahead.
    waypoints = params["waypoints"]
    behind, ahead = params["closest_waypoints"]
    dx = waypoints[ahead][0] - waypoints[behind][0]
    dy = waypoints[ahead][1] - waypoints[behind][1]
    direction = math.atan2(dy, dx)
    error = math.radians(params["heading"]) - direction

    # Speed along the track (m/s): speed across it, or backwards, earns nothing.
    along = params["speed"] * math.cos(error)
    if along <= 0:
        return 1e-3
    reward = max(1e-3, along * along / 4.0)

    # The track's direction LOOK_AHEAD_M further on, waypoint by waypoint.
    count = len(waypoints)
    i, travelled = ahead, 0.0
    while travelled < LOOK_AHEAD_M:
        j = (i + 1) % count
        travelled += math.hypot(
            waypoints[j][0] - waypoints[i][0], waypoints[j][1] - waypoints[i][1]
        )
        i = j
        if i == ahead:  # a track shorter than the look-ahead
            break
    k = (i + 1) % count
    later = math.atan2(waypoints[k][1] - waypoints[i][1], waypoints[k][0] - waypoints[i][0])
    turn = abs((later - direction + math.pi) % (2 * math.pi) - math.pi)
    if params["speed"] > EASE_OFF_ABOVE and turn > math.radians(BEND_DEG):
        reward *= 0.5
    return float(reward)
