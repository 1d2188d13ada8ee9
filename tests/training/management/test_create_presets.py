"""``racecraft_create_model --preset`` and ``--also-train-on``: a model from a preset alone,
a preset with the user's own files over it, several tracks, and clear errors."""

from __future__ import annotations

import io

import pytest
from django.core.management import call_command
from django.core.management.base import CommandError

from training.models import RacingModel
from training.rewards.examples import example_source
from training.rl.presets import RACING

pytestmark = [pytest.mark.django_db, pytest.mark.usefixtures("store_dir", "alice")]


def run(*args: str) -> str:
    out = io.StringIO()
    call_command("racecraft_create_model", "--owner", "alice", *args, stdout=out)
    return out.getvalue()


def test_a_model_from_the_racing_preset_alone() -> None:
    out = run("--name", "racer", "--preset", "racing", "--track", "racecraft_oval")
    model = RacingModel.objects.get(name="racer")
    assert "on racecraft_oval (native)" in out
    assert [{k: a[k] for k in ("steering_angle", "speed")} for a in model.action_space] == (
        RACING.actions()
    )
    assert model.reward_function == example_source("speed_along_track")
    assert model.hyperparameters == RACING.hyperparameters.to_json()
    assert model.neural_network == RACING.network == "RACECRAFT_COMPACT_CNN"


def test_the_users_own_reward_replaces_the_presets(tmp_path) -> None:
    reward = tmp_path / "reward_function.py"
    reward.write_text("def reward_function(params):\n    return float(params['speed'])\n")
    run("--name", "mine", "--preset", "racing", "--reward", str(reward))
    model = RacingModel.objects.get(name="mine")
    assert model.reward_function == reward.read_text()
    assert model.hyperparameters["discount_factor"] == 0.98


def test_also_train_on_several_tracks() -> None:
    out = run("--name", "multi", "--preset", "deepracer_defaults", "--track", "racecraft_oval",
              "--also-train-on", "racecraft_summit:cw", "racecraft_technical")  # fmt: skip
    model = RacingModel.objects.get(name="multi")
    assert model.extra_tracks == [["racecraft_summit", "cw"], ["racecraft_technical", "native"]]
    assert "racecraft_oval (native) + racecraft_summit (cw) + racecraft_technical (native)" in out


@pytest.mark.parametrize(
    "args, message",
    [
        (["--name", "x"], "give --reward and --metadata, or --preset"),
        (["--name", "x", "--preset", "racing", "--also-train-on", "racecraft_summit:up"],
         "--also-train-on 'racecraft_summit:up': give TRACK or TRACK:DIRECTION"),
        (["--name", "x", "--preset", "racing", "--also-train-on", "nowhere"],
         "unknown track 'nowhere' (extra track nowhere)"),
    ],
)  # fmt: skip
def test_clear_errors(args, message) -> None:
    with pytest.raises(CommandError, match=message.replace("(", r"\(").replace(")", r"\)")):
        run(*args)
    assert not RacingModel.objects.exists()
