"""bench/bench_spectator.py's bookkeeping, without training: the hooks want frames only in the
watched run, count them (spare-lap frames apart) and stop after the iterations asked for."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

from training.rl.runner import EvaluationOutcome, IterationResult

PATH = Path(__file__).resolve().parents[2] / "bench" / "bench_spectator.py"


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_spectator_under_test", PATH)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    try:
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(PATH.parent))  # the bench put its folder first, as a script does
    yield module
    del sys.modules[spec.name]


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
