def reward_function(params):
    """Time trial: stay inside the two borders. Any position on the road earns the same."""
    all_wheels_on_track = params["all_wheels_on_track"]
    distance_from_center = params["distance_from_center"]
    track_width = params["track_width"]

    # Keep a small margin from the border so that the wheels stay on the road.
    margin = 0.05
    if all_wheels_on_track and (0.5 * track_width - distance_from_center) >= margin:
        reward = 1.0
    else:
        reward = 1e-3

    return float(reward)
