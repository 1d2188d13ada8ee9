"""The outside-world setting reaches every training episode: the env spec carries it (as JSON,
across the sandbox's process boundary and the simulation queue), the sandboxed rollout worker's
envs draw their conditions from it, and evaluations stay in the clean world."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from training.rl.runner import evaluation_spec
from training.rollout.envs import EnvSpec
from training.rollout.vecenv import LocalVecEnv, SandboxedVecEnv

TRACK = "racecraft_oval"
ACTIONS = [{"steering_angle": a, "speed": 1.0} for a in (-30, 0, 30)]
BRIGHT = {"families": {"light": {"brightness": [40.0, 40.0]}}}
REWARD = "def reward_function(params):\n    return 1.0\n"


def test_the_spec_carries_the_conditions_as_json() -> None:
    spec = EnvSpec(track=TRACK, action_space=ACTIONS, conditions=BRIGHT, conditions_seed=7,
                   tracks=((TRACK, "native"), (TRACK, "cw")))  # fmt: skip
    back = EnvSpec.from_json(json.loads(json.dumps(spec.to_json())))
    assert back == spec and back.conditions == BRIGHT and back.conditions_seed == 7
    assert spec.for_env(1).conditions == BRIGHT  # every car of a multi-track run
    clean = spec.clean()
    assert clean.conditions == {} and clean.conditions_seed is None and clean.track == TRACK
    assert EnvSpec.from_json({"track": TRACK}).conditions == {}  # a spec from before
    # the training run's evaluation laps drive the clean world
    for laps in (1, 3):
        config = SimpleNamespace(spec=spec, eval_laps=laps, eval_from_start_line=False)
        assert evaluation_spec(config).conditions == {}
    env = spec.for_env(0).make(None)
    try:
        _obs, info = env.reset(seed=1)
        assert info["conditions"]["light"]["brightness"] == 40.0
    finally:
        env.close()


@pytest.mark.slow
def test_the_sandboxed_worker_drives_in_the_conditions() -> None:
    """The same seeds give the same pictures in the sandbox as here, and the setting makes
    them brighter than the clean world's."""
    spec = EnvSpec(track=TRACK, action_space=ACTIONS, conditions=BRIGHT)
    means = []
    for venv in (SandboxedVecEnv(spec, 1, REWARD, num_workers=1),
                 LocalVecEnv(spec, 1, None), LocalVecEnv(spec.clean(), 1, None)):  # fmt: skip
        try:
            venv.seed(3)
            obs = venv.reset()
            obs, *_ = venv.step(np.array([1]))
            means.append(float(obs.mean()))
        finally:
            venv.close()
    sandboxed, here, clean = means
    assert sandboxed == pytest.approx(here)
    assert sandboxed > clean + 5  # an ambient veil of 40 gray levels (clipped at white)
