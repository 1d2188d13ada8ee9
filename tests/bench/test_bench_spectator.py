"""bench/bench_spectator.py's bookkeeping, without training: the hooks want frames only in the
watched run, count them (spare-lap frames apart) and stop after the iterations asked for."""

from __future__ import annotations

import pytest

from tests.bench.loader import load_bench
from training.rl.runner import EvaluationOutcome, IterationResult


@pytest.fixture(scope="module")
def bench():
    with load_bench("bench_spectator") as module:
        yield module


def result(iteration: int, steps: int, update_s: float) -> IterationResult:
    return IterationResult(
        iteration=iteration, episodes=20, steps=steps, total_steps=steps * iteration,
        train_reward=1.0, train_progress=10.0, evaluation=EvaluationOutcome([], [], [], []),
        elapsed_s=0.0, rollout_s=1.0, update_s=update_s, eval_s=0.5,
    )  # fmt: skip


def test_only_the_watched_run_wants_frames_and_both_stop_after_their_iterations(bench) -> None:
    unwatched, watched = bench.Watch(False), bench.Watch(True)
    quiet, seen = bench.Hooks(unwatched, 2), bench.Hooks(watched, 2)
    assert not quiet.frames_wanted() and seen.frames_wanted()
    seen.on_frame({"phase": "training"})
    seen.on_frame({"phase": "evaluation", "spare": True})
    assert (watched.frames, watched.spare_frames) == (2, 1)
    for hooks in (quiet, seen):
        hooks.on_iteration(result(1, 800, 2.0), b"", [])
        assert not hooks.should_stop()
        hooks.on_iteration(result(2, 800, 3.0), b"", [])
        assert hooks.should_stop()
    assert unwatched.steps == watched.steps == [800, 1600]
    assert watched.update_s == pytest.approx(5.0) and watched.eval_s == pytest.approx(1.0)
