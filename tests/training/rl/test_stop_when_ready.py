"""The "stop when ready" condition of the training loop: the run ends once
``stop_when_ready`` evaluations in a row have completed every lap, the iteration that completes
the streak becomes the best one, and a failed evaluation starts the count again. Scripted
evaluations here; the same condition through a real training job is in
tests/training/management/test_stop_when_ready_command.py."""

from __future__ import annotations

import pytest

from training.rl import runner
from training.rl.runner import TrainingConfig, TrainingHooks
from training.rollout.envs import EnvSpec
from training.rollout.experience import EvaluationOutcome, Experience

CLEAN = EvaluationOutcome([100.0, 100.0], ["lap_complete"] * 2, [[9.0], [9.5]], [1.0, 1.0])
ONE_OFF = EvaluationOutcome([100.0, 40.0], ["lap_complete", "off_track"], [[9.0], []],
                            [1.0, 0.4])  # fmt: skip
NOWHERE = EvaluationOutcome([10.0, 12.0], ["off_track"] * 2, [[], []], [0.1, 0.1])


class Recorder(TrainingHooks):
    def __init__(self, limit: int) -> None:
        self.limit, self.results = limit, []

    def on_iteration(self, result, checkpoint, rows) -> None:
        self.results.append(result)

    def should_stop(self) -> bool:
        return len(self.results) >= self.limit  # the user's stop, so that no test runs on


def run(monkeypatch, outcomes: list[EvaluationOutcome], *, ready: int, best_score=None,
        streak: int = 0):  # fmt: skip
    """The loop with a source whose evaluations are ``outcomes`` in turn (the user stops it
    after the last), and a model whose update does nothing."""
    script = iter(outcomes)

    class Scripted:
        env = None

        def gather(self, learner) -> Experience | None:
            if learner.stop_reason():
                return None  # as the real sources: a stopped rollout is not learnt from
            learner.model.num_timesteps += 10
            return Experience(steps=10, episodes=[(1.0, 50.0)], rows=[], rollout_s=0.0)

        def evaluate(self, learner, iteration: int) -> None:
            learner.evaluated(iteration, next(script), 0.0)

        def finish(self, learner) -> None:
            pass

        def close(self) -> None:
            pass

    class Model:
        num_timesteps = 0

        def train(self) -> None:
            pass

        def set_logger(self, logger) -> None:
            pass

        def save(self, buffer) -> None:
            buffer.write(b"ckpt")

    class Backend:
        def experience(self, request):
            return Scripted()

    monkeypatch.setattr(runner, "build_model", lambda *args, **kwargs: Model())
    hooks = Recorder(limit=len(outcomes))
    config = TrainingConfig(spec=EnvSpec(track="racecraft_oval"), rollouts=Backend(),
                            stop_when_ready=ready, best_score=best_score,
                            clean_streak=streak)  # fmt: skip
    return runner.train(config, hooks), hooks.results


def test_the_run_ends_ready_at_the_streaks_last_evaluation(monkeypatch):
    outcomes = [NOWHERE, CLEAN, ONE_OFF, CLEAN, CLEAN, CLEAN, NOWHERE, NOWHERE]
    summary, results = run(monkeypatch, outcomes, ready=3)
    assert summary.stopped_by == "ready"
    assert [r.iteration for r in results] == [1, 2, 3, 4, 5, 6]  # nothing learnt after it
    assert summary.best_iteration == 6  # the streak's last, though iteration 2 was as good
    assert [r.best for r in results] == [True, True, False, False, False, True]
    assert summary.best_eval_progress == 100.0


def test_a_failed_evaluation_starts_the_count_again(monkeypatch):
    """Two clean evaluations, a lap missed by one episode, two clean: never three in a row."""
    outcomes = [CLEAN, CLEAN, ONE_OFF, CLEAN, CLEAN]
    summary, results = run(monkeypatch, outcomes, ready=3)
    assert summary.stopped_by == "user" and len(results) == 5
    assert summary.best_iteration == 1  # the first at 100 %, as without the condition


@pytest.mark.parametrize("ready", [0, 1])
def test_off_it_changes_nothing_and_one_stops_at_the_first_clean_evaluation(monkeypatch, ready):
    outcomes = [NOWHERE, ONE_OFF, CLEAN, CLEAN]
    summary, results = run(monkeypatch, outcomes, ready=ready)
    if ready:
        assert summary.stopped_by == "ready" and len(results) == 3
    else:
        assert summary.stopped_by == "user" and len(results) == 4
    assert summary.best_iteration == 3


def test_a_resumed_runs_best_gives_way_to_the_ready_iteration(monkeypatch):
    """A resumed job's best so far (100 %) is beaten by nothing but the ready iteration."""
    summary, results = run(monkeypatch, [CLEAN, CLEAN], ready=2, best_score=100.0)
    assert summary.stopped_by == "ready"
    assert [r.best for r in results] == [False, True]


def test_a_resumed_job_counts_on_from_its_streak(monkeypatch):
    """A job retried after its worker was lost, two clean evaluations into a streak of 3:
    its first clean evaluation completes it; a failed one starts the count again."""
    summary, results = run(monkeypatch, [CLEAN, CLEAN], ready=3, streak=2)
    assert summary.stopped_by == "ready" and len(results) == 1 and results[0].best
    summary, results = run(monkeypatch, [ONE_OFF, CLEAN, CLEAN], ready=3, streak=2)
    assert summary.stopped_by == "user" and len(results) == 3
