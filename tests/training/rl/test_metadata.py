"""model_metadata.json: DeepRacer's examples parse, bad files name the key at fault."""

from __future__ import annotations

import json
from typing import Any

import pytest

from racing.actions import ActionSpec
from training.rl.metadata import (
    MetadataError,
    ModelMetadata,
    build_metadata,
    parse_metadata,
)

# The two examples of deepracer-spec §2.3, verbatim.
DISCRETE_EXAMPLE = """
{"action_space": [{"steering_angle": -30, "speed": 0.5, "index": 0},
                  {"steering_angle": -30, "speed": 1.0, "index": 1}],
 "sensor": ["FRONT_FACING_CAMERA"], "neural_network": "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW",
 "training_algorithm": "clipped_ppo", "action_space_type": "discrete", "version": "5"}
"""
CONTINUOUS_EXAMPLE = """
{"action_space": {"speed": {"high": 2, "low": 1}, "steering_angle": {"high": 30, "low": -30}},
 "sensor": ["FRONT_FACING_CAMERA"], "neural_network": "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW",
 "training_algorithm": "sac", "action_space_type": "continuous", "version": "4"}
"""
CONTINUOUS = {"steering_angle": {"low": -20, "high": 20}, "speed": {"low": 0.5, "high": 3}}


def test_discrete_example() -> None:
    meta = parse_metadata(DISCRETE_EXAMPLE)
    assert meta.action_space_type == "discrete"
    assert meta.actions.actions == ((-30.0, 0.5), (-30.0, 1.0))
    assert meta.training_algorithm == "clipped_ppo"
    assert meta.sensor == ("FRONT_FACING_CAMERA",)
    assert meta.neural_network == "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW"
    assert meta.version == "5"
    assert meta.channels == 1 and meta.observation_shape == (1, 120, 160)
    assert meta.to_json() == json.loads(DISCRETE_EXAMPLE)


def test_continuous_example() -> None:
    meta = parse_metadata(CONTINUOUS_EXAMPLE.encode())
    assert meta.action_space_type == "continuous"
    assert meta.training_algorithm == "sac"
    assert meta.actions.steering_range == (-30.0, 30.0)
    assert meta.actions.speed_range == (1.0, 2.0)
    assert meta.version == "4"
    assert meta.to_json() == json.loads(CONTINUOUS_EXAMPLE)


@pytest.mark.parametrize(
    "sensor, camera, lidar, size",
    [
        (["FRONT_FACING_CAMERA", "LIDAR"], "FRONT_FACING_CAMERA", "LIDAR", 64),
        (["sector_lidar", "STEREO_CAMERAS"], "STEREO_CAMERAS", "SECTOR_LIDAR", 8),
        (["STEREO_CAMERAS", "DISCRETIZED_SECTOR_LIDAR"], "STEREO_CAMERAS",
         "DISCRETIZED_SECTOR_LIDAR", 64),
        (["STEREO_CAMERAS"], "STEREO_CAMERAS", None, 0),
    ],
)  # fmt: skip
def test_deepracer_sensor_combinations(sensor, camera, lidar, size) -> None:
    """deepracer-spec §4: camera or stereo, each alone or with one LIDAR; the camera comes
    first, the observation space is the simulator's (a Dict with a LIDAR)."""
    meta = build_metadata(action_space=CONTINUOUS, sensor=sensor)
    assert meta.sensor == ((camera, lidar) if lidar else (camera,))
    assert meta.camera == camera and meta.lidar == lidar
    space = meta.observation_space
    image_shape = (120, 160, 2 if camera == "STEREO_CAMERAS" else 1)
    if lidar is None:
        assert space.shape == image_shape
    else:
        assert set(space.spaces) == {camera, lidar}
        assert space.spaces[camera].shape == image_shape
        assert space.spaces[lidar].shape == (size,)
    again = parse_metadata(meta.dumps())
    assert again.sensor == meta.sensor


def test_roundtrip_through_bytes() -> None:
    meta = build_metadata(
        action_space=CONTINUOUS,
        sensor=["STEREO_CAMERAS"],
        neural_network="RACECRAFT_LEAN_CNN",
        extra={"preprocess_type": "GREY"},
    )
    again = parse_metadata(meta.dumps())
    assert again == meta
    assert again.channels == 2 and again.extra == {"preprocess_type": "GREY"}
    assert meta.dumps() == again.dumps()  # stable bytes


def test_defaults_for_missing_keys() -> None:
    meta = ModelMetadata.from_json(
        {"action_space": [{"steering_angle": 0, "speed": 1}, {"steering_angle": 10, "speed": 1}]}
    )
    assert meta.action_space_type == "discrete"
    assert meta.training_algorithm == "clipped_ppo"
    assert meta.sensor == ("FRONT_FACING_CAMERA",)
    assert meta.neural_network == "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW"
    assert meta.version == "5"
    # A dict of ranges can only be continuous.
    assert ModelMetadata.from_json({"action_space": CONTINUOUS}).action_space_type == "continuous"


def test_names_are_normalised_and_versions_kept() -> None:
    meta = build_metadata(
        action_space=CONTINUOUS,
        action_space_type="Continuous",
        training_algorithm="SAC",
        sensor=["front_facing_camera"],
        neural_network="deep_convolutional_network",
        version=4,
    )
    assert meta.training_algorithm == "sac" and meta.action_space_type == "continuous"
    assert meta.sensor == ("FRONT_FACING_CAMERA",)
    assert meta.neural_network == "DEEP_CONVOLUTIONAL_NETWORK"
    assert meta.version == "4"
    assert build_metadata(action_space=CONTINUOUS, version="3.0").version == "3.0"


@pytest.mark.parametrize("old_name", ["observation", "LEFT_CAMERA"])
def test_old_camera_names(old_name: str) -> None:
    meta = build_metadata(action_space=CONTINUOUS, sensor=[old_name])
    assert meta.sensor == ("FRONT_FACING_CAMERA",)


def test_action_spec_accepted_directly() -> None:
    spec = ActionSpec.parse(CONTINUOUS)
    assert build_metadata(action_space=spec, training_algorithm="sac").actions is spec


def test_all_networks_accepted() -> None:
    for network in (
        "RACECRAFT_LEAN_CNN",
        "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW",
        "DEEP_CONVOLUTIONAL_NETWORK",
        "DEEP_CONVOLUTIONAL_NETWORK_DEEP",
    ):
        assert build_metadata(action_space=CONTINUOUS, neural_network=network).neural_network == (
            network
        )


def good() -> dict[str, Any]:
    return json.loads(DISCRETE_EXAMPLE)


BAD: list[tuple[str, dict[str, Any] | Any, str, str]] = [
    ("not an object", [1, 2], "model_metadata.json", "JSON object"),
    ("no action space", {"sensor": ["FRONT_FACING_CAMERA"]}, "action_space", "required"),
    ("null action space", {**good(), "action_space": None}, "action_space", "required"),
    (
        "one action",
        {**good(), "action_space": [{"steering_angle": 0, "speed": 1}]},
        "action_space",
        "2-30",
    ),
    (
        "31 actions",
        {**good(), "action_space": [{"steering_angle": 0, "speed": 1}] * 31},
        "action_space",
        "2-30",
    ),
    (
        "steering too wide",
        {
            **good(),
            "action_space": [{"steering_angle": 45, "speed": 1}, {"steering_angle": 0, "speed": 1}],
        },
        "action_space",
        "steering angle",
    ),
    (
        "speed too high",
        {
            **good(),
            "action_space": [{"steering_angle": 0, "speed": 5}, {"steering_angle": 0, "speed": 1}],
        },
        "action_space",
        "speed",
    ),
    (
        "text speed",
        {
            **good(),
            "action_space": [
                {"steering_angle": 0, "speed": "fast"},
                {"steering_angle": 0, "speed": 1},
            ],
        },
        "action_space",
        "number",
    ),
    (
        "continuous low > high",
        {
            "action_space": {
                "steering_angle": {"low": 10, "high": -10},
                "speed": {"low": 1, "high": 2},
            }
        },
        "action_space",
        "steering",
    ),
    (
        "continuous missing speed",
        {"action_space": {"steering_angle": {"low": -10, "high": 10}}},
        "action_space",
        "speed",
    ),
    (
        "type mismatch list",
        {**good(), "action_space_type": "continuous"},
        "action_space_type",
        "says continuous",
    ),
    (
        "type mismatch dict",
        {"action_space": CONTINUOUS, "action_space_type": "discrete"},
        "action_space_type",
        "says discrete",
    ),
    ("unknown type", {**good(), "action_space_type": "hybrid"}, "action_space_type", "one of"),
    (
        "unknown algorithm",
        {**good(), "training_algorithm": "dqn"},
        "training_algorithm",
        "clipped_ppo, sac",
    ),
    (
        "sac with discrete",
        {**good(), "training_algorithm": "sac"},
        "training_algorithm",
        "continuous",
    ),
    ("algorithm not text", {**good(), "training_algorithm": 1}, "training_algorithm", "one of"),
    ("no camera", {**good(), "sensor": []}, "sensor", "exactly one camera"),
    (
        "two cameras",
        {**good(), "sensor": ["FRONT_FACING_CAMERA", "STEREO_CAMERAS"]},
        "sensor",
        "exactly one camera",
    ),
    ("lidar alone", {**good(), "sensor": ["LIDAR"]}, "sensor", "exactly one camera"),
    (
        "two lidars",
        {**good(), "sensor": ["STEREO_CAMERAS", "SECTOR_LIDAR", "LIDAR"]},
        "sensor",
        "at most one LIDAR",
    ),
    ("unknown sensor", {**good(), "sensor": ["THERMAL"]}, "sensor", "unknown sensor"),
    ("sensor not a list", {**good(), "sensor": {"a": 1}}, "sensor", "list"),
    ("unknown network", {**good(), "neural_network": "RESNET"}, "neural_network", "one of"),
    ("network not text", {**good(), "neural_network": None}, "neural_network", "one of"),
    ("version text", {**good(), "version": "latest"}, "version", "version number"),
    ("version zero", {**good(), "version": "0"}, "version", "SimApp version"),
    ("version bool", {**good(), "version": True}, "version", "version number"),
    ("version list", {**good(), "version": [5]}, "version", "version number"),
]


@pytest.mark.parametrize(("data", "field", "words"), [b[1:] for b in BAD], ids=[b[0] for b in BAD])
def test_bad_metadata(data: Any, field: str, words: str) -> None:
    with pytest.raises(MetadataError) as info:
        ModelMetadata.from_json(data)
    assert info.value.field == field
    assert words in str(info.value)
    assert str(info.value).startswith(f"{field}: ")


@pytest.mark.parametrize(
    ("raw", "words"),
    [
        (b"{not json", "not valid JSON"),
        (b'{"action_space": NaN}', "not valid JSON"),
        (b"\xff\xfe{}", "not UTF-8"),
        (b" " * 1_000_001, "larger than"),
    ],
)
def test_bad_files(raw: bytes, words: str) -> None:
    with pytest.raises(MetadataError, match=words) as info:
        parse_metadata(raw)
    assert info.value.field == "model_metadata.json"


def test_utf8_bom_accepted() -> None:
    assert parse_metadata("\ufeff" + DISCRETE_EXAMPLE).version == "5"
