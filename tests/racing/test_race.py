"""RaceConfig: DeepRacer's race settings, validated, and JSON-able for worker processes."""

from __future__ import annotations

import json

import pytest

from racing.race import RaceConfig, RaceType


def test_round_trips_through_json():
    config = RaceConfig(
        race_type=RaceType.OBJECT_AVOIDANCE,
        object_positions=((0.2, 1), (0.5, -1)),
        bot_lane_change=True,
    )
    data = json.loads(json.dumps(config.to_dict()))
    assert data["race_type"] == "OBJECT_AVOIDANCE"
    assert data["object_positions"] == [[0.2, 1], [0.5, -1]]
    assert RaceConfig.from_dict(data) == config
    # Fixed positions set the number of objects.
    assert config.number_of_objects == 2


def test_race_type_from_its_id():
    config = RaceConfig(race_type="HEAD_TO_BOT")
    assert config.race_type is RaceType.HEAD_TO_BOT
    assert config.has_bots and not config.has_boxes
    assert RaceConfig().race_type is RaceType.TIME_TRIAL


@pytest.mark.parametrize(
    "settings, message",
    [
        ({"race_type": "F1"}, "race_type must be one of"),
        ({"number_of_objects": 0}, "number_of_objects must be an integer from 1 to 6"),
        ({"number_of_bots": 7}, "number_of_bots must be an integer from 1 to 6"),
        ({"object_positions": [(0.3, 2)]}, "a lane is 1"),
        ({"object_positions": [(0.95, 1)]}, "outside 0.07-0.9"),
        ({"object_positions": [(0.3, 1), (0.4, -1)]}, "closer than 0.13"),
        ({"bot_speed": 7.0}, "bot_speed must be 0.2-6.0"),
        ({"lane_change_min_s": 5.0, "lane_change_max_s": 3.0}, "lane_change_min_s"),
        ({"min_bot_gap_m": 0.0}, "min_bot_gap_m must be positive"),
    ],
)
def test_refuses_what_deepracer_refuses(settings, message):
    with pytest.raises(ValueError, match=message):
        RaceConfig(**settings)


def test_from_dict_refuses_unknown_and_malformed_settings():
    with pytest.raises(ValueError, match="unknown race setting"):
        RaceConfig.from_dict({"number_of_boxes": 3})
    with pytest.raises(ValueError, match="list of \\[track fraction, lane\\] pairs"):
        RaceConfig.from_dict({"object_positions": [0.3]})
