"""Races between racers (training.services.challenges): Alice races her car against Bob's once
Bob opens it to challenges, and is refused while it is closed; frozen copies race, so Bob
closing and deleting his model later changes nothing; limits and quota refuse with a clear
message and create nothing; races take turns in the fair order with other users' races, and
a race day's race keeps its own token."""

from __future__ import annotations

import pytest
from django.contrib.auth import get_user_model
from django.utils import timezone

from tests.support import constant
from training import services
from training.errors import ServiceError
from training.interchange.layout import RaceKeys
from training.models import JobStatus, RaceJob, RacingModel
from training.services import challenges
from training.services.job_queue import fair_order
from training.services.jobs import JobQuotaError
from training.store import get_store
from training.worker.race import run_race_job

pytestmark = pytest.mark.django_db
RACE = {"track_id": "racecraft_oval", "laps": 1}


@pytest.fixture
def cars(racer_model):
    """Alice's car and Bob's (closed to challenges, as every model starts)."""
    return racer_model("alice", constant(0, 1.0)), racer_model("bob", constant(-5, 1.5))


def test_a_racer_races_an_open_model_and_is_refused_a_closed_one(cars):
    alice_car, bob_car = cars
    alice, bob = alice_car.owner, bob_car.owner
    with pytest.raises(ServiceError, match="not open to challenges") as refused:
        challenges.challenge_start(user=alice, model_id=alice_car.pk,
                                   opponent_ids=[bob_car.pk], **RACE)  # fmt: skip
    assert refused.value.field == "opponents" and not RaceJob.objects.exists()
    assert challenges.challenge_choices(user=alice).opponents == [alice_car]

    challenges.model_challenges_set(model=bob_car, user=bob, open_=True)
    assert challenges.challenge_choices(user=alice).opponents == [alice_car, bob_car]
    race = challenges.challenge_start(user=alice, model_id=alice_car.pk,
                                      opponent_ids=[bob_car.pk], **RACE)  # fmt: skip
    assert (race.owner, race.purpose, race.status) == (alice, "challenge", JobStatus.QUEUED)
    assert list(race.opponents.all()) == [bob]
    store = get_store()
    for entry, model in zip(race.entries, (alice_car, bob_car), strict=True):
        assert entry["checkpoint"] == RaceKeys.frozen_checkpoint(f"race-{race.pk}", model.pk)
        assert store.get_bytes(entry["checkpoint"])  # a frozen copy of its best checkpoint
        assert entry["metadata"] == services.model_metadata(model).to_json()

    # Bob closes his model and deletes it before the race runs: its frozen copy still races.
    challenges.model_challenges_set(model=bob_car, user=bob, open_=False)
    bob_id = bob_car.pk
    services.model_delete(model=bob_car, user=bob)
    RaceJob.objects.filter(pk=race.pk).update(time_limit_s=10.0)  # short: a test
    assert run_race_job(race.pk, "test") == "completed"
    race.refresh_from_db()
    cars_ = {car["model"]: car for car in race.car_rows}
    assert set(cars_) == {alice_car.pk, bob_id} and cars_[bob_id]["reason"] == ""
    assert race.has_video and store.get_bytes(RaceKeys(race.pk).video)[4:8] == b"ftyp"

    assert challenges.challenge_role(race, alice) == challenges.CHALLENGER
    assert challenges.challenge_role(race, bob) == challenges.OPPONENT
    charlie = get_user_model().objects.create_user("charlie")
    assert challenges.challenge_role(race, charlie) is None
    [row] = challenges.races_against(user=bob)
    assert row["challenger"] == "alice" and row["mine"][0]["result"]["model"] == bob_id
    assert challenges.races_against(user=alice) == []
    assert challenges.challenge_traces(race)[:2] == b"\x1f\x8b"  # every car's trace, gzipped


@pytest.mark.parametrize(
    ("change", "field", "words"),
    [
        ({"laps": 6}, "laps", "laps must be 1 to 5"),
        ({"laps": "x"}, "laps", "whole number"),
        ({"bots": 7}, "bots", "bot cars must be 0 to 6"),
        ({"direction": "up"}, "direction", "direction"),
        ({"track_id": "nowhere"}, "track_id", "unknown track"),
        ({"opponents": []}, "opponents", "pick 1 to 3 opponents"),
        ({"opponents": ["mine"]}, "opponents", "only one place on the grid"),
        ({"opponents": ["bob", "bob"]}, "opponents", "only one place on the grid"),
        ({"model": "bob", "opponents": ["mine"]}, "model", "your own models"),
        ({"model": "untrained"}, "model", "no trained checkpoint"),
    ],
)
def test_limits_are_refused_with_their_field_and_nothing_is_created(store_dir, change, field,
                                                                    words):  # fmt: skip
    users = get_user_model().objects
    alice, bob = users.create_user("alice"), users.create_user("bob")

    def model(owner, name: str, **flags) -> object:  # refused before any weights are read
        made = services.model_create(
            owner=owner,
            name=name,
            track_id="racecraft_oval",
            action_space=constant(0, 1.0),
            validate_reward=False,
            reward_function="def reward_function(p):\n    return 1.0\n",
        )
        RacingModel.objects.filter(pk=made.pk).update(**flags)
        return made

    alice_car = model(alice, "alice-car", has_checkpoint=True)
    bob_car = model(bob, "bob-car", has_checkpoint=True, open_to_challenges=True)
    untrained = model(alice, "untrained")
    ids = {"mine": alice_car.pk, "bob": bob_car.pk, "untrained": untrained.pk}
    args = {"model_id": alice_car.pk, "opponent_ids": [bob_car.pk], **RACE}
    for key, value in change.items():
        if key == "opponents":
            args["opponent_ids"] = [ids[v] for v in value]
        elif key == "model":
            args["model_id"] = ids[value]
        else:
            args[key] = value
    with pytest.raises(ServiceError, match=words) as refused:
        challenges.challenge_start(user=alice, **args)
    assert refused.value.field == field
    assert not RaceJob.objects.exists()


def test_a_full_quota_refuses_the_race_and_creates_nothing(cars, settings):
    settings.RACECRAFT_MAX_ACTIVE_JOBS_PER_USER = 1
    alice_car, bob_car = cars
    challenges.model_challenges_set(model=bob_car, user=bob_car.owner, open_=True)
    first = challenges.challenge_start(user=alice_car.owner, model_id=alice_car.pk,
                                       opponent_ids=[bob_car.pk], **RACE)  # fmt: skip
    with pytest.raises(JobQuotaError, match="1 jobs queued or running"):
        challenges.challenge_start(user=alice_car.owner, model_id=alice_car.pk,
                                   opponent_ids=[bob_car.pk], **RACE)  # fmt: skip
    assert list(RaceJob.objects.values_list("pk", flat=True)) == [first.pk]
    assert not get_store().list(f"league/race-{first.pk + 1}/")
    # Bob's quota is his own: Alice's race against his car is not charged to him.
    challenges.model_challenges_set(model=alice_car, user=alice_car.owner, open_=True)
    challenges.challenge_start(user=bob_car.owner, model_id=bob_car.pk,
                               opponent_ids=[alice_car.pk], **RACE)  # fmt: skip


def test_races_take_turns_by_user_and_a_race_days_race_keeps_its_token(db):
    users = get_user_model().objects
    alice, bob = users.create_user("alice"), users.create_user("bob")
    start = timezone.now() - timezone.timedelta(hours=1)

    def queued(owner, n: int, *, at: float, **extra) -> RaceJob:
        return RaceJob.objects.create(
            owner=owner, track_id="racecraft_oval", task_id=f"t-{owner}-{n}",
            created_at=start + timezone.timedelta(seconds=at), **extra,
        )  # fmt: skip

    a = [queued(alice, i, at=i) for i in range(3)]  # Alice queued three races first,
    b = queued(bob, 0, at=10)  # then Bob one,
    day = queued(None, 9, at=5, paced=True)  # and a race day put one on track.
    assert fair_order(RaceJob) == [a[0].pk, b.pk, a[1].pk, a[2].pk]
    assert services.jobs_ahead(RaceJob.objects.get(pk=b.pk)) == 1

    def claim(job: RaceJob) -> RaceJob:
        token = RaceJob.objects.get(pk=job.pk).task_id
        return services.job_claim(job_model=RaceJob, job_id=job.pk, worker="w@host",
                                  task_id=token)  # fmt: skip

    assert claim(a[0]).pk == a[0].pk
    taken = claim(a[1])  # Alice's second token runs Bob's race; Alice's keeps Bob's token
    assert taken.pk == b.pk and RaceJob.objects.get(pk=a[1].pk).task_id == "t-bob-0"
    assert claim(day).pk == day.pk  # the race day's own token, never another's
    assert RaceJob.objects.get(pk=day.pk).task_id == "t-None-9"
