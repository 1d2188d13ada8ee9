"""``racecraft_create_model --conditions`` and ``--condition``: the outside-world setting from
the command line, and clear errors."""

from __future__ import annotations

import io

import pytest
from django.core.management import call_command
from django.core.management.base import CommandError

from training.models import RacingModel

pytestmark = [pytest.mark.django_db, pytest.mark.usefixtures("store_dir", "alice")]


def run(*args: str) -> str:
    out = io.StringIO()
    call_command("racecraft_create_model", "--owner", "alice", "--preset", "racing",
                 "--track", "racecraft_oval", *args, stdout=out)  # fmt: skip
    return out.getvalue()


def test_families_and_a_narrowed_range() -> None:
    out = run("--name", "outside", "--conditions", "light,camera", "--condition",
              "light.brightness=-20:20", "--condition", "camera.blur=0.5")  # fmt: skip
    model = RacingModel.objects.get(name="outside")
    families = model.conditions["families"]
    assert list(families) == ["light", "camera"]
    assert families["light"]["brightness"] == [-20.0, 20.0]
    assert families["camera"]["blur"] == [0.5, 0.5]
    assert families["camera"]["noise"] == [0.0, 6.0]  # left out: its training range
    assert "outside world: light, camera" in out
    run("--name", "clean")
    assert RacingModel.objects.get(name="clean").conditions == {}


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (("--conditions", "light,fog"), "no condition family 'fog'"),
        (("--conditions", "light", "--condition", "light.brightness=-90:0"), "widest range"),
        (("--conditions", "light", "--condition", "camera.blur=0:1"), "turn on the family"),
        (("--conditions", "light", "--condition", "light.brightness"), "FAMILY.PARAMETER=LOW"),
        (("--condition", "light.gamma=1:1.2"), "turn on the family .light."),
    ],
)
def test_bad_settings_say_what_is_wrong(args, words) -> None:
    with pytest.raises(CommandError, match=words):
        run("--name", "bad", *args)
    assert not RacingModel.objects.exists()


def test_the_curriculum_is_the_recommended_one_unless_told() -> None:
    from racing.conditions import RECOMMENDED_RAMP_EPISODES

    run("--name", "eased", "--conditions", "light")
    assert RacingModel.objects.get(name="eased").conditions["ramp_episodes"] == (
        RECOMMENDED_RAMP_EPISODES
    )
    run("--name", "sudden", "--conditions", "light", "--conditions-ramp", "0")
    assert "ramp_episodes" not in RacingModel.objects.get(name="sudden").conditions
    run("--name", "slow", "--conditions", "light", "--conditions-ramp", "400")
    assert RacingModel.objects.get(name="slow").conditions["ramp_episodes"] == 400
    with pytest.raises(CommandError, match="ramp_episodes must be a whole number"):
        run("--name", "bad", "--conditions", "light", "--conditions-ramp", "-1")
