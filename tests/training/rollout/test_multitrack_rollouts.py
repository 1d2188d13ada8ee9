"""Multi-track rollouts: a spec deals its tracks to the run's envs in turn, across workers,
through the spec's JSON, in-process and in sandboxed workers; each finished episode names the
track it was driven on."""

from __future__ import annotations

import numpy as np
import pytest

from training.rollout.envs import EnvSpec
from training.rollout.vecenv import LocalVecEnv, SandboxedVecEnv, first_envs

TWO = (("racecraft_oval", "native"), ("racecraft_summit", "cw"))
ACTIONS = [{"steering_angle": a, "speed": 3.0} for a in (-30, 0, 30)]
REWARD = """
def reward_function(params):
    return 1.0 if params["all_wheels_on_track"] else 1e-3
"""


def test_for_env_deals_the_tracks_in_turn() -> None:
    spec = EnvSpec(track="racecraft_oval", tracks=TWO, action_space=ACTIONS)
    dealt = [spec.for_env(i) for i in range(5)]
    assert [(s.track, s.direction) for s in dealt] == [*TWO, *TWO, TWO[0]]
    assert all(s.tracks == () and s.action_space == ACTIONS for s in dealt)
    assert spec.track_list() == TWO


def test_a_one_track_spec_is_its_own_env_spec() -> None:
    spec = EnvSpec(track="racecraft_oval", direction="cw")
    assert spec.for_env(3) is spec
    assert spec.track_list() == (("racecraft_oval", "cw"),)


def test_the_tracks_survive_json_and_old_json_has_none() -> None:
    spec = EnvSpec(track="racecraft_oval", tracks=TWO)
    data = spec.to_json()
    assert data["tracks"] == [list(pair) for pair in TWO]
    assert EnvSpec.from_json(data) == spec
    del data["tracks"]
    assert EnvSpec.from_json(data).tracks == ()


def test_each_worker_knows_its_first_env() -> None:
    assert first_envs([4, 4]) == [0, 4]
    assert first_envs([3, 3, 2]) == [0, 3, 6]


def drive_until_each_env_finished(venv, limit: int = 2000) -> list[dict]:
    """Random actions until every env has finished an episode; the episodes' entries."""
    rng = np.random.default_rng(0)
    venv.seed(1)
    venv.reset()
    finished: dict[int, dict] = {}
    for _ in range(limit):
        _, _, dones, infos = venv.step(rng.integers(0, len(ACTIONS), venv.num_envs))
        for i in np.flatnonzero(dones):
            finished.setdefault(int(i), infos[i]["episode_entry"])
        if len(finished) == venv.num_envs:
            break
    venv.close()
    return [finished[i] for i in sorted(finished)]


def test_in_process_envs_drive_their_own_tracks() -> None:
    spec = EnvSpec(track="racecraft_oval", tracks=TWO, action_space=ACTIONS)
    venv = LocalVecEnv(spec, 4, lambda params: 1.0)
    assert [e.track.track_id for e in venv.runner.envs] == [t for t, _ in TWO] * 2
    alone = [EnvSpec(track=t, direction=d).make() for t, d in TWO]
    assert [e.track.is_reversed for e in venv.runner.envs] == [
        a.track.is_reversed for a in alone
    ] * 2
    entries = drive_until_each_env_finished(venv)
    assert [e["track"] for e in entries] == [t for t, _ in TWO] * 2


@pytest.mark.slow
def test_sandboxed_workers_deal_tracks_across_the_run() -> None:
    """3 envs on 2 workers (2 + 1): the second worker's env is the run's third, on track 0."""
    spec = EnvSpec(
        track="racecraft_oval",
        tracks=(*TWO, ("racecraft_technical", "native")),
        action_space=ACTIONS,
    )
    venv = SandboxedVecEnv(spec, 3, REWARD, num_workers=2)
    entries = drive_until_each_env_finished(venv)
    assert [e["track"] for e in entries] == ["racecraft_oval", "racecraft_summit",
                                              "racecraft_technical"]  # fmt: skip
