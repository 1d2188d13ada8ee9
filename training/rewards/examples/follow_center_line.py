def reward_function(params):
    """Time trial: follow the centre line. Pays more the closer the car stays to it."""
    track_width = params["track_width"]
    distance_from_center = params["distance_from_center"]

    # Three bands around the centre line, as fractions of the track width.
    if distance_from_center <= 0.1 * track_width:
        reward = 1.0
    elif distance_from_center <= 0.25 * track_width:
        reward = 0.5
    elif distance_from_center <= 0.5 * track_width:
        reward = 0.1
    else:
        reward = 1e-3  # probably off track

    return float(reward)
