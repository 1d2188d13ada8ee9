"""Saving a reward function from the web: the check answers a value (ready, needs_validation
with the validation it queued, or refused), never an exception; the model services pass it
on instead of saving, and the command line's modes still raise a refusal."""

from __future__ import annotations

import pytest
from celery import current_app

from tests.training.services.factory import create
from training.errors import RewardRejected, ServiceError
from training.models import RacingModel
from training.services import model_update_reward, rewards
from training.services.rewards import RewardCheck, RewardStatus

pytestmark = [pytest.mark.django_db, pytest.mark.usefixtures("store_dir")]

GOOD = "def reward_function(params):\n    return 1.0\n"
BROKEN = "def reward_function(params):\n    return (\n"
OVAL = [("racecraft_oval", "native")]


@pytest.fixture
def queued(monkeypatch, settings) -> list[dict]:
    """The validations sent to the workers (none runs here)."""
    settings.RACECRAFT_VALIDATIONS_PER_USER = 100
    settings.RACECRAFT_VALIDATIONS_PER_MINUTE = 100
    sent: list[dict] = []
    monkeypatch.setattr(current_app, "send_task", lambda name, **kw: sent.append(kw["kwargs"]))
    return sent


def check(user, source: str, how: str = "passed", tracks=OVAL) -> RewardCheck:
    return rewards.reward_check_before_save(user=user, source=source, tracks=tracks, how=how)


def test_without_a_pass_a_validation_is_queued_and_its_id_answered(alice, queued) -> None:
    answer = check(alice, GOOD)
    assert answer.status is RewardStatus.NEEDS_VALIDATION and not answer.is_ready
    assert answer.task_id and answer.error is None and answer.errors == []
    assert queued == [{"source": GOOD, "track_id": "racecraft_oval", "direction": "native",
                       "user_id": alice.pk}]  # fmt: skip
    status = rewards.reward_validation_status(user_id=alice.pk, task_id=answer.task_id)
    assert status == {"status": "queued"}


def test_a_pass_on_every_track_is_ready_and_the_first_without_one_is_validated(
    alice, queued
) -> None:
    rewards.reward_validation_remember(
        user_id=alice.pk, source=GOOD, track_id="racecraft_oval", direction="native"
    )
    assert check(alice, GOOD) == RewardCheck.ready()
    two = [*OVAL, ("racecraft_oval", "cw")]
    assert check(alice, GOOD, tracks=two).status is RewardStatus.NEEDS_VALIDATION
    assert [q["direction"] for q in queued] == ["cw"]


def test_parse_errors_and_limits_are_refused_with_their_reason(alice, queued, settings) -> None:
    answer = check(alice, BROKEN)
    assert answer.status is RewardStatus.REFUSED and isinstance(answer.error, RewardRejected)
    assert answer.errors and answer.errors[0]["lineNumber"] == 2
    assert queued == []
    settings.RACECRAFT_VALIDATIONS_PER_USER = 0
    limited = check(alice, GOOD)
    assert limited.status is RewardStatus.REFUSED and limited.errors == []
    assert limited.error.field == "reward_function"
    assert "validations running" in limited.error.message


def test_no_check_is_ready_and_an_unknown_mode_is_a_mistake(alice) -> None:
    assert check(alice, BROKEN, how="none").is_ready
    with pytest.raises(ValueError):
        check(alice, GOOD, how="maybe")


def test_the_model_services_answer_the_check_instead_of_saving(alice, queued) -> None:
    created = create(alice, reward_function=GOOD, validate_reward=True, reward_check="passed")
    assert isinstance(created, RewardCheck)
    assert created.status is RewardStatus.NEEDS_VALIDATION
    assert not RacingModel.objects.exists()
    refused = create(alice, reward_function=BROKEN, validate_reward=True, reward_check="passed")
    assert isinstance(refused, RewardCheck) and refused.status is RewardStatus.REFUSED
    model = create(alice, reward_function=GOOD)
    edit = model_update_reward(model=model, user=alice, reward_function=GOOD + "\n",
                               reward_check="passed")  # fmt: skip
    assert isinstance(edit, RewardCheck) and edit.status is RewardStatus.NEEDS_VALIDATION
    model.refresh_from_db()
    assert model.reward_function == GOOD


def test_the_command_lines_mode_still_raises_a_refusal(alice) -> None:
    with pytest.raises(RewardRejected):
        create(alice, reward_function=BROKEN, validate_reward=True)
    with pytest.raises(ServiceError):
        create(alice, reward_function="  ", validate_reward=True)
