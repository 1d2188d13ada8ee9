import math


def reward_function(params):
    """Time trial: prevent zig-zag. Follow the centre line and penalise hard steering."""
    distance_from_center = params["distance_from_center"]
    track_width = params["track_width"]
    steering = abs(params["steering_angle"])  # degrees, sign says left or right

    # Closeness to the centre line, from 1 (on it) down to 0 (at the border), smoothly.
    closeness = max(0.0, 1.0 - distance_from_center / (0.5 * track_width))
    reward = 1e-3 + closeness**2

    # Steering more than this (degrees) costs reward: smooth lines, no zig-zag.
    abs_steering_threshold = 15.0
    if steering > abs_steering_threshold:
        reward *= 0.8 * math.cos(math.radians(steering - abs_steering_threshold))

    return float(reward)
