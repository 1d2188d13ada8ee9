"""Issue 22, item 8: the reward code shares its process with the rollout's simulator, so with the
Python guard bypassed it can change what that simulator reports. That fakes only the racer's
own training: the laps that count (evaluations, leaderboard submissions) are driven in a
process that never loaded a reward function, and refuse to run in one that did."""

from __future__ import annotations

import numpy as np
import pytest

from tests.training.sandbox.sandbox_support import TRACK_ID
from training.rl.evaluation import EvaluationSettings, evaluate
from training.rollout.envs import EnvSpec
from training.rollout.vecenv import SandboxedVecEnv
from training.sandbox import taint

#: Finds the simulator beside it and makes every step report a finished lap.
POKE = """
import gc

def reward_function(params):
    for o in gc.get_objects():
        if type(o).__name__ == "RacingEnv" and not getattr(type(o), "poked", False):
            real = type(o).step

            def step(self, action):
                obs, reward, done, truncated, info = real(self, action)
                info["progress"] = 100.0
                info["status"] = "lap_complete"
                return obs, reward, done, truncated, info

            type(o).step, type(o).poked = step, True
    return 1.0
"""


def _straight(obs):
    return 0  # the first action, whatever it is: a policy that finishes no lap quickly


def test_a_poked_simulator_fakes_only_the_racers_own_rollout() -> None:
    spec = EnvSpec(track=TRACK_ID)
    rollout = SandboxedVecEnv(spec, 1, POKE, num_workers=1, python_guards=False)
    try:
        rollout.reset()
        infos = []
        for _ in range(5):
            _, _, _, step_infos = rollout.step(np.array([0]))
            infos += step_infos
    finally:
        rollout.close()
    # The rollout's simulator is the user's: it now says every step finished the lap.
    assert [i["progress"] for i in infos[1:]] == [100.0] * 4
    # The judge is another process, untouched: the same straight policy, honestly driven.
    assert not taint.tainted()
    report = evaluate(_straight, spec, EvaluationSettings(laps=3, resets=0, record_video=False))
    assert report.completed_laps == 0
    assert all(lap.progress < 100.0 for lap in report.laps)


def test_an_evaluation_refuses_to_run_where_user_code_was_loaded(monkeypatch) -> None:
    monkeypatch.setattr(taint, "_tainted", True)
    with pytest.raises(taint.TaintedProcess, match="loaded a reward function"):
        evaluate(_straight, EnvSpec(track=TRACK_ID), EvaluationSettings(record_video=False))
