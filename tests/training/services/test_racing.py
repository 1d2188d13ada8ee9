"""Race types as the services accept them: object avoidance and head-to-bot settings checked
with DeepRacer's numbers, stored on the model and its evaluations, and carried to the
simulator in the jobs' env spec. (Alice owns the models.)"""

from __future__ import annotations

import pytest

from racing.race import RaceConfig, RaceType
from tests.training.services.factory import create
from training import services
from training.models import EvaluationJob, RacingModel
from training.services import ServiceError
from training.worker.common import env_spec

pytestmark = [pytest.mark.django_db, pytest.mark.usefixtures("store_dir")]


def test_time_trial_has_no_settings_and_others_get_defaults():
    assert services.race_settings("TIME_TRIAL", {}) == {}
    boxes = services.race_settings("OBJECT_AVOIDANCE", {"number_of_objects": 4})
    assert boxes["race_type"] == "OBJECT_AVOIDANCE" and boxes["number_of_objects"] == 4
    assert boxes["randomize_objects"] is False
    bots = services.race_settings("HEAD_TO_BOT", {"bot_speed": 6, "bot_lane_change": True})
    assert bots["number_of_bots"] == 2 and bots["bot_speed"] == 6 and bots["bot_lane_change"]


def test_a_new_head_to_bot_race_has_the_bots_at_the_consoles_speed_not_the_simulators():
    bots = services.race_settings("HEAD_TO_BOT", {})
    assert bots["bot_speed"] == services.RACE_DEFAULTS["bot_speed"] == 0.5
    assert RaceConfig().bot_speed == 0.2  # DeepRacer's simulator default, kept in racing/
    boxes = services.race_settings("OBJECT_AVOIDANCE", {"object_positions": [[0.3, 1]]})
    assert boxes["number_of_objects"] == 1  # positions still set the count


@pytest.mark.parametrize(
    "race_type, given, field, words",
    [
        ("OBJECT_AVOIDANCE", {"number_of_objects": 0}, "number_of_objects", "1 to 6"),
        ("OBJECT_AVOIDANCE", {"object_positions": [[0.05, 1]]}, "object_positions", "0.07-0.9"),
        ("OBJECT_AVOIDANCE", {"object_positions": [[0.3, 1], [0.35, -1]]}, "object_positions",
         "closer than 0.13"),
        ("HEAD_TO_BOT", {"number_of_bots": 7}, "number_of_bots", "1 to 6"),
        ("HEAD_TO_BOT", {"bot_speed": 0.1}, "bot_speed", "0.2-6.0 m/s"),
        ("HEAD_TO_BOT", {"lane_change_min_s": 5, "lane_change_max_s": 3}, "lane_change_min_s",
         "lane_change_min_s <= lane_change_max_s"),
        ("HEAD_TO_BOT", {"randomize_objects": True}, "race_type", "no setting"),
        ("F1", {}, "race_type", "unknown race type"),
    ],
)  # fmt: skip
def test_bad_race_settings_name_their_field(race_type, given, field, words):
    with pytest.raises(ServiceError, match=words) as err:
        services.race_settings(race_type, given)
    assert err.value.field == field


def test_object_positions_are_read_as_deepracer_for_cloud_writes_them():
    assert services.parse_object_positions("0.23,-1; 0.46,1") == [[0.23, -1], [0.46, 1]]
    assert services.parse_object_positions("  ") == []
    with pytest.raises(ServiceError, match="box 2: write each position") as err:
        services.parse_object_positions("0.2,1;0.5")
    assert err.value.field == "object_positions"


def test_sensor_advice_follows_deepracer():
    assert services.sensor_advice("TIME_TRIAL", ["FRONT_FACING_CAMERA"]) == ""
    assert "stereo" in services.sensor_advice("OBJECT_AVOIDANCE", ["FRONT_FACING_CAMERA"])
    assert services.sensor_advice("OBJECT_AVOIDANCE", ["FRONT_FACING_CAMERA", "LIDAR"]) == ""
    assert "LIDAR" in services.sensor_advice("HEAD_TO_BOT", ["STEREO_CAMERAS"])
    assert services.sensor_advice("HEAD_TO_BOT", ["STEREO_CAMERAS", "SECTOR_LIDAR"]) == ""


def test_a_model_keeps_its_race_and_sensors_and_its_jobs_drive_them(alice):
    model = create(
        alice,
        race_type="OBJECT_AVOIDANCE",
        race_config={"number_of_objects": 2, "randomize_objects": True},
        sensors=["STEREO_CAMERAS", "LIDAR"],
    )
    model.refresh_from_db()
    assert model.sensors == ["STEREO_CAMERAS", "LIDAR"]
    assert model.race_config["number_of_objects"] == 2 and model.race_config["randomize_objects"]
    meta = services.model_metadata(model)
    assert meta.sensor == ("STEREO_CAMERAS", "LIDAR")
    spec = env_spec(model)
    assert spec.race["race_type"] == "OBJECT_AVOIDANCE"
    assert spec.sensors == ("STEREO_CAMERAS", "LIDAR")
    env = spec.make(None)
    try:
        env.reset(seed=1)
        assert len(env.objects) == 2 and set(env.observation_space.spaces) == {
            "STEREO_CAMERAS",
            "LIDAR",
        }
    finally:
        env.close()
    clone = services.model_clone(model=model, owner=alice, name="m2")
    assert clone.race_type == "OBJECT_AVOIDANCE" and clone.race_config == model.race_config


def test_an_evaluation_runs_the_models_race_or_the_one_asked(alice):
    model = create(alice, race_type="HEAD_TO_BOT", race_config={"number_of_bots": 3})
    RacingModel.objects.filter(pk=model.pk).update(has_checkpoint=True)
    own = services.evaluation_start(model=model, user=alice, enqueue=False)
    assert own.race_type == "HEAD_TO_BOT" and own.race_config["number_of_bots"] == 3
    EvaluationJob.objects.filter(pk=own.pk).update(status="COMPLETED")
    RacingModel.objects.filter(pk=model.pk).update(status=RacingModel.Status.READY)
    other = services.evaluation_start(
        model=model, user=alice, race_type="OBJECT_AVOIDANCE",
        race_config={"number_of_objects": 5}, enqueue=False,
    )  # fmt: skip
    assert other.race_config["number_of_objects"] == 5
    race = services.race_config(other.race_type, other.race_config)
    assert race.race_type is RaceType.OBJECT_AVOIDANCE and race.number_of_objects == 5
    spec = env_spec(model, race=race)
    assert spec.race["number_of_objects"] == 5
    with pytest.raises(ServiceError, match="1 to 6") as err:
        services.evaluation_start(model=model, user=alice, race_type="HEAD_TO_BOT",
                                  race_config={"number_of_bots": 9}, enqueue=False)  # fmt: skip
    assert err.value.field == "number_of_bots"
