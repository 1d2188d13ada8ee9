"""A race's live speed control in the race worker (training/worker/race.py): a multiplier set
through training's service while the race runs drives the car from the next step, and each
step's multiplier is in the car's sim-trace as a last column that the community's reader,
deepracer-utils, reads without complaint (its 19 columns unchanged). Alice's car is sped up;
Bob's is left alone."""

from __future__ import annotations

import io

import pytest
import redis
from django.contrib.auth import get_user_model

from racing.simtrace import SIMTRACE_COLUMNS, SPEED_MULTIPLIER_COLUMN
from tests.support import constant
from training.interchange.layout import RaceKeys
from training.models import RaceJob
from training.services import race_plan
from training.services.race_control import race_speed_set
from training.services.races import race_start
from training.worker.race import run_race_job

pytestmark = [pytest.mark.django_db, pytest.mark.slow]


@pytest.fixture(autouse=True)
def _no_speeds_between_tests(settings):
    yield
    client = redis.Redis.from_url(settings.REDIS_URL)
    keys = list(client.scan_iter(match=f"{settings.REDIS_PREFIX}racecraft:race-speed:*"))
    if keys:
        client.delete(*keys)
    client.close()


def test_a_speed_set_during_the_race_drives_the_car_and_is_in_its_trace(racer_model, store_dir):
    alice = racer_model("alice", constant(0, 1.0))
    bob = racer_model("bob", constant(0, 1.0))
    plan = race_plan(model_ids=[alice.pk, bob.pk], track_id="racecraft_oval", laps=1,
                     time_limit_s=10.0, record_video=False)  # fmt: skip
    steward = get_user_model().objects.create_user("steward", is_staff=True)
    job = race_start(plan=plan, user=steward, enqueue=False)
    race_speed_set(race=job, index=0, multiplier="1.5")  # Alice, before the race starts
    assert run_race_job(job.pk, "test") == "completed"
    job = RaceJob.objects.get(pk=job.pk)
    keys = RaceKeys(job.pk)
    folders = {m.pk: store_dir / keys.car_folder(m.pk) for m in (alice, bob)}
    texts = {}
    for pk, folder in folders.items():
        (trace,) = folder.glob("evaluation-*/evaluation-simtrace/0-iteration.csv")
        texts[pk] = trace.read_text()
    header = texts[alice.pk].split("\n")[0].split(",")
    assert header == [*SIMTRACE_COLUMNS, SPEED_MULTIPLIER_COLUMN]  # DeepRacer's 19, then ours
    speeds = {pk: [line.split(",")[-1] for line in text.strip().split("\n")[1:]]
              for pk, text in texts.items()}  # fmt: skip
    assert set(speeds[alice.pk]) == {"1.50"}  # set before the start: from the first step
    assert set(speeds[bob.pk]) == {"1.00"}
    # Same actions, Alice faster: the distance each car drove in its first second (15 steps).
    pd = pytest.importorskip("pandas")
    frames = {pk: pd.read_csv(io.StringIO(text)) for pk, text in texts.items()}
    metres = {pk: float(((f["X"].diff() ** 2 + f["Y"].diff() ** 2) ** 0.5)[1:15].sum())
              for pk, f in frames.items()}  # fmt: skip
    assert metres[alice.pk] > 1.3 * metres[bob.pk]
    assert frames[alice.pk][SPEED_MULTIPLIER_COLUMN].iloc[-1] == 1.5
    logs = pytest.importorskip("deepracer.logs")
    for pk, folder in folders.items():
        log = logs.DeepRacerLog(model_folder=str(folder))
        log.load_evaluation_trace(force=True)
        frame = log.dataframe()
        assert len(frame) == len(speeds[pk]) and frame["speed"].eq(1.0).all()  # throttle
        assert SPEED_MULTIPLIER_COLUMN in frame.columns
        agg = logs.AnalysisUtils.simulation_agg(frame, firstgroup="stream", is_eval=True)
        assert len(agg) >= 1 and agg["steps"].sum() == len(frame)
