"""Race types and sensors on the command line: ``racecraft_create_model`` stores the race and
sensors the services would, ``racecraft_evaluate`` evaluates in the model's race or another,
and a setting the services refuse comes back as an error naming its option."""

from __future__ import annotations

import io
import json

import pytest
from django.core.management import call_command
from django.core.management.base import CommandError

from tests.support import CENTRE_LINE_REWARD as REWARD
from tests.support import OVAL_ACTIONS as ACTIONS
from training import services
from training.management import cli
from training.management.commands import racecraft_create_model, racecraft_evaluate
from training.models import EvaluationJob, JobStatus, RacingModel
from training.store import get_store, keys_for

pytestmark = [pytest.mark.django_db, pytest.mark.usefixtures("store_dir", "alice")]


def create(*args: str) -> str:
    out = io.StringIO()
    call_command("racecraft_create_model", "--owner", "alice", "--preset", "racing",
                 "--track", "racecraft_oval", *args, stdout=out)  # fmt: skip
    return out.getvalue()


def evaluate(model: RacingModel, *args: str) -> str:
    out = io.StringIO()
    call_command("racecraft_evaluate", str(model.pk), "--queue", *args, stdout=out)
    return out.getvalue()


def test_an_object_avoidance_model_with_stereo_cameras_and_a_lidar() -> None:
    out = create("--name", "dodger", "--race-type", "object_avoidance", "--box-positions",
                 "0.25:1", "0.5:-1", "--sensor", "stereo_cameras", "--sensor", "LIDAR")  # fmt: skip
    model = RacingModel.objects.get(name="dodger")
    assert model.race_type == "OBJECT_AVOIDANCE"
    assert model.race_config == services.race_settings(
        "OBJECT_AVOIDANCE", {"object_positions": [[0.25, 1], [0.5, -1]]}
    )
    assert model.race_config["number_of_objects"] == 2
    assert model.sensors == ["STEREO_CAMERAS", "LIDAR"]
    metadata = json.loads(get_store().get_bytes(keys_for(model.pk).metadata))
    assert metadata["sensor"] == ["STEREO_CAMERAS", "LIDAR"]
    assert "STEREO_CAMERAS, LIDAR" in out and "object avoidance (2 boxes, fixed)" in out
    assert "Note:" not in out  # stereo and a LIDAR are what DeepRacer recommends


def test_a_head_to_bot_model_from_a_comma_list_of_sensors() -> None:
    out = create("--name", "chaser", "--race-type", "HEAD_TO_BOT", "--bots", "3",
                 "--bot-speed", "1.5", "--bot-lane-change", "--lane-change-min", "2",
                 "--sensor", "FRONT_FACING_CAMERA,SECTOR_LIDAR")  # fmt: skip
    model = RacingModel.objects.get(name="chaser")
    assert model.race_config == services.race_settings("HEAD_TO_BOT", {
        "number_of_bots": 3, "bot_speed": 1.5, "bot_lane_change": True, "lane_change_min_s": 2.0,
    })  # fmt: skip
    assert model.sensors == ["FRONT_FACING_CAMERA", "SECTOR_LIDAR"]
    assert "head-to-bot (3 bots at 1.5 m/s, changing lanes)" in out
    assert "Note: DeepRacer recommends stereo cameras with a LIDAR" in out


def test_a_head_to_bot_model_without_settings_gets_the_wizards_defaults() -> None:
    from console.race_form import RaceSettingsForm

    out = create("--name", "plain", "--race-type", "head_to_bot")
    model = RacingModel.objects.get(name="plain")
    form = RaceSettingsForm(data={"race_type": "HEAD_TO_BOT"})
    assert form.is_valid(), form.errors
    assert model.race_config == form.race_config(form.cleaned_data)
    assert model.race_config["bot_speed"] == 0.5 and model.race_config["number_of_bots"] == 2
    assert "head-to-bot (2 bots at 0.5 m/s)" in out


@pytest.mark.parametrize(
    "args, message",
    [
        (["--race-type", "head_to_bot", "--bot-speed", "9"],
         "--bot-speed: --bot-speed must be 0.2-6.0 m/s, not 9.0"),
        (["--bots", "2"], "--race-type: Time trial has no setting --bots"),
        (["--race-type", "object_avoidance", "--boxes", "7"],
         "--boxes: --boxes must be an integer from 1 to 6, not 7"),
        (["--race-type", "object_avoidance", "--box-positions", "0.95:1"],
         "--box-positions: object position 0.95 is outside 0.07-0.9"),
        (["--race-type", "object_avoidance", "--box-positions", "0.3:2"],
         r"--box-positions: a lane is 1 \(inner\) or -1 \(outer\), not 2"),
        (["--race-type", "object_avoidance", "--box-positions", "0.3"],
         "argument --box-positions: write each box as FRACTION:LANE"),
        (["--race-type", "head_to_bot", "--lane-change-min", "4", "--lane-change-max", "2"],
         "--lane-change-min: lane change times need 0 < --lane-change-min <= --lane-change-max"),
        (["--sensor", "LIDAR"], "--sensor: choose exactly one camera"),
        (["--sensor", "STEREO_CAMERAS,SONAR"], "--sensor: unknown sensor 'SONAR'"),
        (["--race-type", "drag"], "argument --race-type: invalid choice: 'drag'"),
    ],
)  # fmt: skip
def test_a_refused_setting_names_its_option(args, message) -> None:
    with pytest.raises(CommandError, match=message):
        create("--name", "x", *args)
    assert not RacingModel.objects.exists()


def test_help_lists_the_race_types_sensors_and_settings() -> None:
    for command in (racecraft_create_model.Command(), racecraft_evaluate.Command()):
        text = command.create_parser("manage.py", "x").format_help()
        assert "{time_trial,object_avoidance,head_to_bot}" in text
        for option in ("--boxes", "--box-positions", "--randomize-boxes", "--bots",
                       "--bot-speed", "--bot-lane-change", "--lane-change-max"):  # fmt: skip
            assert option in text, (command, option)
    text = racecraft_create_model.Command().create_parser("manage.py", "x").format_help()
    assert "--sensor SENSOR" in text and "SECTOR_LIDAR" in text and "STEREO_CAMERAS" in text


def test_evaluations_in_the_models_race_or_another(alice, monkeypatch) -> None:
    # --queue in a test transaction: the job is only stored (on_commit never fires), and the
    # Ctrl-C below stops following it; the worker tests run race evaluations for real.
    model = services.model_create(
        owner=alice, name="h2b", track_id="racecraft_oval", action_space=ACTIONS,
        reward_function=REWARD, validate_reward=False, race_type="HEAD_TO_BOT",
        race_config={"number_of_bots": 3, "bot_speed": 1.0}, sensors=["STEREO_CAMERAS", "LIDAR"],
    )  # fmt: skip
    RacingModel.objects.filter(pk=model.pk).update(has_checkpoint=True)

    def ctrl_c(seconds: float) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "pause", ctrl_c)

    def evaluation(*args: str) -> tuple[EvaluationJob, str]:
        out = evaluate(model, *args)
        job = EvaluationJob.objects.get(model=model, status=JobStatus.QUEUED)
        services.job_stop(job=job, user=alice)
        return job, out

    own, out = evaluation()
    assert own.race_type == "HEAD_TO_BOT" and own.race_config == model.race_config
    assert "head-to-bot (3 bots at 1 m/s)" in out

    changed, out = evaluation("--bot-lane-change", "--bots", "1")
    assert changed.race_type == "HEAD_TO_BOT"
    assert changed.race_config == services.race_settings("HEAD_TO_BOT", {
        "number_of_bots": 1, "bot_speed": 1.0, "bot_lane_change": True,
    })  # fmt: skip
    assert "head-to-bot (1 bot at 1 m/s, changing lanes)" in out

    boxes, _ = evaluation("--race-type", "object_avoidance", "--boxes", "2", "--randomize-boxes")
    assert boxes.race_type == "OBJECT_AVOIDANCE"
    assert boxes.race_config == services.race_settings(
        "OBJECT_AVOIDANCE", {"number_of_objects": 2, "randomize_objects": True}
    )

    with pytest.raises(CommandError, match="--bot-speed: --bot-speed must be 0.2-6.0 m/s"):
        evaluate(model, "--bot-speed", "0.1")
    assert EvaluationJob.objects.filter(model=model).count() == 3
