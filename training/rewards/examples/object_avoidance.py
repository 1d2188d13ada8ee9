import math


def reward_function(params):
    """Object avoidance: stay on one lane and do not crash into objects ahead."""
    all_wheels_on_track = params["all_wheels_on_track"]
    distance_from_center = params["distance_from_center"]
    track_width = params["track_width"]
    objects_location = params["objects_location"]
    x, y = params["x"], params["y"]
    _, next_object = params["closest_objects"]
    is_left_of_center = params["is_left_of_center"]
    objects_left_of_center = params["objects_left_of_center"]

    reward = 1e-3
    # Lane keeping: on the road and within the inner 80 % of the road.
    if all_wheels_on_track and (0.5 * track_width - distance_from_center) >= 0.05:
        reward_lane = 1.0
    else:
        reward_lane = 1e-3

    reward_avoid = 1.0
    if objects_location:
        ox, oy = objects_location[next_object]
        distance = math.hypot(x - ox, y - oy)
        same_lane = objects_left_of_center[next_object] == is_left_of_center
        if same_lane:
            if distance < 0.5:
                reward_avoid = 1e-3
            elif distance < 0.8:
                reward_avoid *= 0.2
            elif distance < 1.5:
                reward_avoid *= 0.5

    # Lane keeping matters less than not crashing.
    reward += 1.0 * reward_lane + 4.0 * reward_avoid
    return float(reward)
