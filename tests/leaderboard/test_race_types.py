"""Object-avoidance and head-to-bot events: submissions accepted, evaluated by the real
evaluation job (the simulator with the event's boxes or bots, its collision penalty and
respawns) and ranked. A scripted driver stands in for the trained policy: the checkpoint is
still loaded, but the driver steers, so a lap's result does not depend on training."""

from __future__ import annotations

import numpy as np
import pytest
from league_helpers import make_event, make_model

from leaderboard.access import LeagueError
from leaderboard.events import event_race
from leaderboard.models import Submission
from leaderboard.selectors import leaderboard_rows
from leaderboard.services import submission_create
from racing.controllers import AvoidingDriver
from training import services
from training.rl.checkpoints import checkpoint_bytes, new_model
from training.store import get_store, keys_for
from training.worker.evaluation import run_evaluation_job

pytestmark = [pytest.mark.django_db, pytest.mark.usefixtures("store_dir")]
CONTINUOUS = {"steering_angle": {"low": -30, "high": 30}, "speed": {"low": 0.5, "high": 2.0}}


def racer_model(owner, name: str):
    """A READY model with a real (untrained) checkpoint in the store."""
    model = make_model(owner, name, action_space_type="continuous", action_space=CONTINUOUS)
    data = checkpoint_bytes(new_model(services.model_metadata(model)))
    get_store().put_bytes(keys_for(model.pk).best, data)
    return model


@pytest.fixture
def drivers(monkeypatch):
    """Run evaluation jobs with a scripted driver per racer; ``drivers[name]`` is set by the
    test to ``"clean"`` (dodges every box) or ``"bump"`` (runs into the first box once, then
    dodges). The env the job builds is captured so the driver can see its objects."""
    import training.rl.evaluation as evaluation
    import training.worker.evaluation as worker

    made: dict = {}
    original = evaluation.evaluation_env

    def capture(spec, settings):
        env = original(spec, settings)
        made["env"] = env
        made["driver"] = AvoidingDriver(env.track, max_speed=1.2)
        made["bumped"] = False
        return env

    def policy(obs):
        env, driver = made["env"], made["driver"]
        made["bumped"] = made["bumped"] or env.tracker.current_lap.crashes > 0
        if made["style"] == "bump" and not made["bumped"] and env.objects:
            target = env.objects[0]
            loc = env.track.locate(target.x, target.y)
            driver.offset = loc.distance if loc.left else -loc.distance  # aim at the box
            steer, speed = driver.act(env.pose)
        else:
            steer, speed = driver.act_among(env.pose, env.objects)
        return np.array([steer, speed], dtype=np.float32)

    monkeypatch.setattr(evaluation, "evaluation_env", capture)
    monkeypatch.setattr(worker, "sb3_policy", lambda model: policy)
    return made


def submit_and_run(event, user, model, drivers, style: str) -> Submission:
    drivers["style"] = style
    submission = submission_create(event=event, user=user, model=model)
    assert run_evaluation_job(submission.evaluation_id) == "completed"
    submission.refresh_from_db()
    return submission


def test_event_race_settings_follow_the_race_rules(fran):
    assert event_race(make_event(fran)) == {}
    boxes = event_race(make_event(fran, race_type="OBJECT_AVOIDANCE", number_of_objects=4,
                                  randomize_objects=True))  # fmt: skip
    assert boxes["number_of_objects"] == 4 and boxes["randomize_objects"]
    bots = event_race(make_event(fran, race_type="HEAD_TO_BOT", bot_count=2, bot_speed_mps=0.75,
                                 bot_lane_changes=True))  # fmt: skip
    assert (bots["number_of_bots"], bots["bot_speed"], bots["bot_lane_change"]) == (2, 0.75, True)
    with pytest.raises(LeagueError, match="1 to 6") as err:
        event_race(make_event(fran, race_type="OBJECT_AVOIDANCE", number_of_objects=0))
    assert err.value.field == "number_of_objects"
    with pytest.raises(LeagueError, match="1 to 6") as err:
        event_race(make_event(fran, race_type="HEAD_TO_BOT", bot_count=0))
    assert err.value.field == "bot_count"


@pytest.mark.slow
def test_object_avoidance_event_ranks_with_collision_penalties(fran, alice, bob, drivers):
    """Total time of 3 laps around 2 boxes with a 5 s collision penalty: Bob's car hits a box
    once (5 s frozen, respawned behind it in the other lane) and ranks behind Alice's clean
    run; the evaluation was run in the event's race (the boxes in the env)."""
    event = make_event(fran, race_type="OBJECT_AVOIDANCE", number_of_objects=2,
                       ranking_method="TOTAL_TIME", min_laps=3, max_laps=3,
                       collision_penalty_s=5.0)  # fmt: skip
    clean = submit_and_run(event, alice, racer_model(alice, "dodger"), drivers, "clean")
    assert len(drivers["env"].objects) == 2
    assert clean.evaluation.race_type == "OBJECT_AVOIDANCE"
    assert clean.evaluation.race_config["number_of_objects"] == 2
    assert clean.status == Submission.Status.RANKED, clean.reason
    assert clean.collisions == 0 and clean.consecutive_laps == 3
    bumped = submit_and_run(event, bob, racer_model(bob, "bumper"), drivers, "bump")
    assert bumped.status == Submission.Status.RANKED, bumped.reason
    assert bumped.collisions == 1
    crash_lap = next(lap for lap in bumped.laps if lap["crashes"])
    assert crash_lap["crash_penalty_s"] == 5.0 and crash_lap["resets"] == 1
    # The frozen 5 s are in Bob's time: he is behind Alice by at least most of them.
    assert bumped.score_ms - clean.score_ms > 3000
    rows = leaderboard_rows(event)
    assert [r.alias for r in rows] == ["Alice-R", "BobRacer"]


@pytest.mark.slow
def test_head_to_bot_event_is_evaluated_among_bots_and_ranked(fran, alice, drivers):
    event = make_event(fran, race_type="HEAD_TO_BOT", bot_count=1, bot_speed_mps=0.3,
                       ranking_method="BEST_LAP", min_laps=1, max_laps=3,
                       collision_penalty_s=5.0)  # fmt: skip
    submission = submit_and_run(event, alice, racer_model(alice, "overtaker"), drivers, "clean")
    env = drivers["env"]
    assert len(env.objects) == 1 and env.objects[0].kind == "bot"
    assert submission.evaluation.race_config["bot_speed"] == 0.3
    assert submission.status == Submission.Status.RANKED, submission.reason
    assert submission.score_ms == submission.best_lap_ms > 0
    (row,) = leaderboard_rows(event)
    assert row.alias == "Alice-R"
