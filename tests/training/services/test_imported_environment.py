"""Where an imported archive's training parameters put the model: the track and the driving
direction as Racecraft, DeepRacer-for-Cloud and DeepRacer-on-AWS each write it."""

from __future__ import annotations

import pytest

from training.services.model_imports import _imported_environment


@pytest.mark.parametrize(
    ("params", "direction"),
    [
        ({}, "native"),
        ({"REVERSE_DIR": "True"}, "cw"),  # DeepRacer-for-Cloud
        ({"REVERSE_DIR": "false"}, "native"),
        ({"TRACK_DIRECTION_CLOCKWISE": "true"}, "cw"),  # DeepRacer-on-AWS
        ({"TRACK_DIRECTION_CLOCKWISE": "false"}, "ccw"),
        ({"TRACK_DIRECTION_CLOCKWISE": "maybe"}, "native"),
        ({"RACECRAFT_DIRECTION": "ccw", "TRACK_DIRECTION_CLOCKWISE": "true"}, "ccw"),
        ({"RACECRAFT_DIRECTION": "sideways"}, "native"),
    ],
)
def test_the_driving_direction_of_each_tools_training_params(params, direction):
    track_id, found, *_ = _imported_environment({"WORLD_NAME": "racecraft_oval", **params})
    assert (track_id, found) == ("racecraft_oval", direction)
