"""Streamed training (issue 14) on its own, no Django: simulation worker processes drive whole
episodes with their copy of the policy and stream them through the tests' real Redis; the
trainer learns from the current version's episodes only, evaluates while it updates, and
resumes from a checkpoint."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from gymnasium import spaces

from training.rl.checkpoints import load_checkpoint
from training.rl.hyperparams import parse_hyperparameters
from training.rl.metadata import build_metadata
from training.rl.runner import TrainingConfig, TrainingHooks, experience_request, train
from training.rl.simulation import launch_local
from training.rollout.backends import StreamRollouts
from training.rollout.buffers import rollout_buffer
from training.rollout.envs import EnvSpec
from training.rollout.lockstep import LockstepExperience
from training.rollout.streamed import StreamedExperience, worker_count

DISCRETE = [{"steering_angle": a, "speed": v} for a in (-30, 0, 30) for v in (1.0, 2.0)]
REWARD = """
def reward_function(params):
    return params["speed"] if params["all_wheels_on_track"] else 1e-3
"""


def reference_gae(rewards, values, *, terminated: bool, bootstrap: float, gamma: float,
                  lam: float) -> np.ndarray:  # fmt: skip
    """GAE(λ) of one whole episode, written out: a terminated episode's last step has no
    future; one cut by the time limit bootstraps from the value of its last observation."""
    n, last = len(rewards), 0.0
    advantages = np.zeros(n)
    for t in reversed(range(n)):
        next_value = (0.0 if terminated else bootstrap) if t == n - 1 else values[t + 1]
        delta = rewards[t] + gamma * next_value - values[t]
        last = delta + (gamma * lam * last if t < n - 1 else 0.0)
        advantages[t] = last
    return advantages


def test_streamed_episodes_fill_the_buffer_with_gae_per_episode_for_a_terminated_and_a_cut_one():
    """The streamed buffer is filled as the lockstep one (one function, SB3's GAE): two
    episodes in a row as one env, the first terminated, the second cut by the time limit (its
    bootstrap added to its last reward), hold each episode's own GAE(λ); chunks of an episode
    join up in order."""
    from types import SimpleNamespace

    from training.rollout.streams import Chunk

    rng = np.random.default_rng(3)
    gamma, lam = 0.99, 0.95
    lengths, terminated, bootstrap = [5, 4], [True, False], [0.0, 0.7]
    rewards = [rng.normal(size=n).astype(np.float32) for n in lengths]
    values = [rng.normal(size=n).astype(np.float32) for n in lengths]
    model = SimpleNamespace(observation_space=spaces.Box(0, 1, (1,)),
                            action_space=spaces.Discrete(2), device="cpu", gamma=gamma,
                            gae_lambda=lam)  # fmt: skip

    def chunk(e: int, part: slice, seq: int, last: bool) -> Chunk:
        n = len(rewards[e][part])
        return Chunk(ticket=f"0:{e}", attempt=f"a{e}", worker="w0", version=0, seq=seq,
                     obs=np.full((n, 1), e, np.float32), actions=np.zeros(n, np.int64),
                     log_probs=np.full(n, -0.5, np.float32), values=values[e][part],
                     rewards=rewards[e][part], infos=[{}] * n, last=last,
                     terminated=terminated[e], bootstrap=bootstrap[e])  # fmt: skip

    episodes = [[chunk(0, slice(0, 2), 0, False), chunk(0, slice(2, 5), 1, True)],
                [chunk(1, slice(0, 4), 0, True)]]  # fmt: skip
    buffer = rollout_buffer(model, episodes)
    expected = np.concatenate([
        reference_gae(r, v, terminated=t, bootstrap=b, gamma=gamma, lam=lam)
        for r, v, t, b in zip(rewards, values, terminated, bootstrap, strict=True)
    ])  # fmt: skip
    assert buffer.full and buffer.pos == buffer.buffer_size == sum(lengths)
    assert np.allclose(buffer.advantages[:, 0], expected, atol=1e-5)
    assert np.allclose(buffer.returns[:, 0], expected + np.concatenate(values), atol=1e-5)
    assert buffer.episode_starts[:, 0].tolist() == [1, 0, 0, 0, 0, 1, 0, 0, 0]
    assert buffer.observations[:, 0, 0].tolist() == [0] * 5 + [1] * 4
    assert np.allclose(buffer.log_probs, -0.5)


class Collect(TrainingHooks):
    def __init__(self, iterations: int, watch: bool = False) -> None:
        self.iterations, self.watch = iterations, watch
        self.results, self.checkpoints, self.rows, self.episodes, self.frames = [], [], [], [], []

    def on_episode(self, entry: dict) -> None:
        self.episodes.append(entry)

    def on_iteration(self, result, checkpoint, rows) -> None:
        self.results.append(result)
        self.checkpoints.append(checkpoint)
        self.rows.append(rows)

    def frames_wanted(self) -> bool:
        return self.watch

    def on_frame(self, frame: dict) -> None:
        self.frames.append(frame)

    def should_stop(self) -> bool:
        return len(self.results) >= self.iterations


class CollectUntilTrainingFrames(Collect):
    """As :class:`Collect`, and on until a training episode's frame came (8 iterations at
    most): which worker is watched, and whether it drives a training episode while watched
    or an evaluation lap, depends on the machine's load."""

    def should_stop(self) -> bool:
        seen = any(f["phase"] == "training" for f in self.frames)
        return len(self.results) >= (self.iterations if seen else 8)


def _config(redis_url: str, prefix: str, **overrides) -> TrainingConfig:
    values = {
        "spec": EnvSpec(track="racecraft_oval", action_space=DISCRETE),
        "hyperparameters": parse_hyperparameters(
            {"num_episodes_between_training": 4, "num_epochs": 3, "batch_size": 32}
        ),
        "max_minutes": 60,  # the hooks stop it, however loaded the machine is
        "reward_source": REWARD,
        "eval_episodes": 2,
        "rollouts": StreamRollouts(
            redis_url=redis_url, workers=2, launch=launch_local, prefix=prefix
        ),
    }
    values.update(overrides)
    return TrainingConfig(**values)


@pytest.mark.slow
def test_streamed_iterations_with_evaluations_and_live_frames(redis_url, settings):
    config = _config(redis_url, settings.REDIS_PREFIX)
    hooks = CollectUntilTrainingFrames(iterations=2, watch=True)
    summary = train(config, hooks)
    # Every finished update gets its row, its evaluation as far as it got at the stop.
    assert summary.stopped_by == "user" and summary.iterations >= 2
    assert [r.iteration for r in hooks.results] == list(range(1, summary.iterations + 1))
    print([(r.rollout_s, r.update_s, r.eval_s, r.evaluation.progress) for r in hooks.results])
    for result in hooks.results:
        assert result.episodes == 4  # the quota, once each
        assert result.steps > 0 and result.rollout_s > 0 and result.update_s > 0
        assert len(result.evaluation.progress) <= 2
        assert all(0.0 <= p <= 100.0 for p in result.evaluation.progress)
    assert hooks.results[0].best
    assert len(hooks.episodes) >= 8
    assert all(len(row) == 20 for row in hooks.rows[0])  # 19 sim-trace values + the car
    assert hooks.results[1].total_steps == hooks.results[0].total_steps + hooks.results[1].steps
    # Frames say what is happening, from the first iteration's training episodes on.
    assert hooks.frames, "no live frame arrived"
    assert {f["phase"] for f in hooks.frames} <= {"training", "evaluation"}
    assert any(f["phase"] == "training" and f["iteration"] >= 1 for f in hooks.frames)
    assert all(f["camera"].dtype == np.uint8 and f["camera"][:2].tolist() == [0xFF, 0xD8]
               for f in hooks.frames)  # fmt: skip
    metadata = build_metadata(action_space=DISCRETE, sensor=["FRONT_FACING_CAMERA"],
                              neural_network="RACECRAFT_LEAN_CNN")  # fmt: skip
    model = load_checkpoint(hooks.checkpoints[-1], metadata)  # nothing unpickled
    assert model.num_timesteps == hooks.results[-1].total_steps


@pytest.mark.slow
def test_streamed_training_resumes_from_a_checkpoint(redis_url, settings):
    first = Collect(iterations=1)
    train(_config(redis_url, settings.REDIS_PREFIX), first)
    again = Collect(iterations=1)
    train(_config(redis_url, settings.REDIS_PREFIX, initial_checkpoint=first.checkpoints[0]),
          again)  # fmt: skip
    assert again.results[0].total_steps > first.results[0].total_steps  # steps carried on


@pytest.mark.slow
def test_a_reward_error_in_a_simulation_worker_is_a_clear_error(redis_url, settings):
    from training.sandbox import RewardFunctionError

    bad = "def reward_function(params):\n    return 1.0 / 0\n"
    with pytest.raises(RewardFunctionError, match="ZeroDivisionError") as caught:
        train(_config(redis_url, settings.REDIS_PREFIX, reward_source=bad), Collect(1))
    assert caught.value.error.line == 2  # the job names the line, as with lockstep rollouts


CONTINUOUS = {"steering_angle": {"low": -30, "high": 30}, "speed": {"low": 0.5, "high": 3.0}}


@pytest.mark.slow
@pytest.mark.parametrize("actions", [DISCRETE, CONTINUOUS], ids=["discrete", "continuous"])
def test_a_streamed_episode_is_on_policy_in_the_trainers_buffer(redis_url, settings, actions):
    """What a worker computed (log-probabilities, values) is what the trainer's copy of the
    same policy gives for the buffer's observations and actions: the trip through the stream
    (compression, channel order, action encoding, chunks) loses nothing PPO relies on."""
    import dataclasses
    import uuid

    from training.rl.hyperparams import Hyperparameters
    from training.rl.simulation import SimulationWorker
    from training.rollout.streams import Session, read_chunk

    spec = EnvSpec(track="racecraft_oval", action_space=actions)
    session = Session(redis_url, settings.REDIS_PREFIX, uuid.uuid4().hex)
    session.create()
    session.r.set(session.keys.trainer, 1, ex=60)
    hp = dataclasses.asdict(Hyperparameters())
    worker = SimulationWorker(session, "w0", spec=spec, eval_spec=spec, reward_source=REWARD,
                              algorithm="clipped_ppo", network="RACECRAFT_LEAN_CNN",
                              hyperparameters=hp, seed=1)  # fmt: skip
    try:
        worker.version = 0
        worker.beat.start()
        assert worker.training_episode("0:0")
        model = worker.model
        dim = 0 if actions is DISCRETE else 2
        chunks = [read_chunk(m, (120, 160, 1), dim) for _, m in session.read("t", 1000)]
        assert chunks[-1].last and all(c.ticket == "0:0" for c in chunks)
        buffer = rollout_buffer(model, [chunks])
        assert buffer.buffer_size == sum(c.steps for c in chunks)
        data = next(buffer.get(None))
        taken = data.actions.long().flatten() if dim == 0 else data.actions
        with torch.no_grad():
            values, log_probs, _ = model.policy.evaluate_actions(data.observations, taken)
        assert torch.allclose(log_probs, data.old_log_prob, atol=1e-4)
        assert torch.allclose(values.flatten(), data.old_values, atol=1e-4)
    finally:
        worker.close()
        session.cleanup()
        session.close()


def test_a_scored_evaluation_lap_is_driven_in_the_env_worker(redis_url, settings, monkeypatch):
    """A simulation worker's scored lap goes to its env's sandboxed worker with the network
    (chunks of steps; the network only with the first) and reports what the lap driven step by
    step with torch reports."""
    import dataclasses
    import uuid

    from training.rl import simulation
    from training.rl.hyperparams import Hyperparameters
    from training.rl.simulation import SimulationWorker
    from training.rollout.streams import Session

    spec = EnvSpec(track="racecraft_oval", action_space=DISCRETE)
    from_the_line = EnvSpec.from_json({**spec.to_json(), "start": "start_line",
                                       "alternate_direction": False})  # fmt: skip
    session = Session(redis_url, settings.REDIS_PREFIX, uuid.uuid4().hex)
    session.create()
    session.r.set(session.keys.trainer, 1, ex=60)
    worker = SimulationWorker(session, "w0", spec=spec, eval_spec=from_the_line,
                              reward_source=REWARD,
                              algorithm="clipped_ppo", network="RACECRAFT_TINY_TEST_CNN",
                              hyperparameters=dataclasses.asdict(Hyperparameters()),
                              seed=4)  # fmt: skip
    drives: list[bool] = []
    send_drive = type(worker.eval_env).send_drive

    def sent(env, net, steps):
        drives.append(net is not None)
        send_drive(env, net, steps)

    monkeypatch.setattr(type(worker.eval_env), "send_drive", sent)
    try:
        worker.version = 0
        worker.beat.start()
        assert worker.evaluation_lap(None, "e:0")
        assert drives and drives[0] and not any(drives[1:])
        chunks = len(drives)
        monkeypatch.setattr(simulation, "export_greedy", lambda policy: None)
        assert worker.evaluation_lap(None, "e:1")  # torch, a step at a time
        assert len(drives) == chunks
        laps = [m for _, m in session.read("t", 1000) if m.get("kind") == "eval"]
        assert [m["ticket"] for m in laps] == ["e:0", "e:1"]
        keys = ("progress", "status", "reward", "lap_times")
        assert [laps[0][k] for k in keys] == [laps[1][k] for k in keys]
    finally:
        worker.close()
        session.cleanup()
        session.close()


def _chunk(ticket: str, attempt: str, seq: int, *, version: int = 0, last: bool = True) -> dict:
    from training.rollout.streams import chunk_message

    steps = 3
    return chunk_message(
        ticket=ticket, attempt=attempt, worker="w", version=version, seq=seq,
        obs=np.zeros((steps, 120, 160, 1), np.uint8), actions=np.zeros(steps),
        log_probs=np.zeros(steps), values=np.zeros(steps), rewards=np.ones(steps),
        infos=[{"status": "in_progress"}] * steps, last=last, terminated=True,
    )  # fmt: skip


def test_the_trainer_counts_an_episode_once_and_only_whole_and_current(redis_url, settings):
    """Without workers: chunk messages as a dead, a slow and a repeated worker would send."""
    config = _config(redis_url, settings.REDIS_PREFIX)
    loop = config.rollouts.experience(experience_request(config))
    assert isinstance(loop, StreamedExperience)
    try:
        loop._take(_chunk("0:0", "dead", 0, last=False), version=0, quota=2)  # then it died
        loop._take(_chunk("0:0", "again", 0, last=False), version=0, quota=2)  # driven again
        loop._take(_chunk("0:0", "again", 2), version=0, quota=2)  # a gap: not whole
        assert loop.counted == {}
        loop._take(_chunk("0:1", "late", 0, version=1), version=0, quota=2)  # not this version
        loop._take(_chunk("0:0", "third", 0, last=False), version=0, quota=2)
        loop._take(_chunk("0:0", "third", 1), version=0, quota=2)
        assert list(loop.counted) == ["0:0"] and len(loop.counted["0:0"]) == 2
        loop._take(_chunk("0:0", "dead", 1), version=0, quota=2)  # a late copy of a counted one
        assert list(loop.counted) == ["0:0"] and loop.counted_tickets == ["0:0"]
    finally:
        loop.close()


THREE_TRACKS = (
    ("racecraft_oval", "native"), ("racecraft_summit", "native"),
    ("racecraft_technical", "native"),
)  # fmt: skip


def test_a_multi_track_run_starts_a_worker_for_every_track():
    one = EnvSpec(track="racecraft_oval")
    three = EnvSpec(track="racecraft_oval", tracks=THREE_TRACKS)
    assert worker_count(2, one) == 2 and worker_count(0, one) == 1
    assert worker_count(2, three) == 3 and worker_count(4, three) == 4


class CollectUntilEveryTrack(Collect):
    """Trains on until an episode of every track came in (10 iterations at most): which
    worker claims which episode depends on how fast each one started."""

    def should_stop(self) -> bool:
        driven = {e["track"] for e in self.episodes}
        return len(self.results) >= 10 or driven >= {t for t, _ in THREE_TRACKS}


@pytest.mark.slow
def test_a_streamed_run_on_more_tracks_than_workers_drives_every_track(redis_url, settings):
    spec = EnvSpec(track="racecraft_oval", tracks=THREE_TRACKS, action_space=DISCRETE)
    config = _config(redis_url, settings.REDIS_PREFIX, spec=spec, eval_episodes=1)
    assert config.rollouts.workers == 2  # fewer than the tracks
    hooks = CollectUntilEveryTrack(iterations=1)
    train(config, hooks)
    assert {e["track"] for e in hooks.episodes} == {t for t, _ in THREE_TRACKS}


def test_the_stream_backend_serves_ppo_on_a_users_camera_reward_and_the_rest_in_lockstep(
    redis_url, settings
):
    """SAC learns after every step, a trusted callable cannot travel and a LIDAR observation
    is not streamed: those run in lockstep on the trainer's machine, with as many workers."""
    lidar = EnvSpec(track="racecraft_oval", action_space=DISCRETE,
                    sensors=("FRONT_FACING_CAMERA", "LIDAR"))  # fmt: skip
    cases = {
        "ppo": ({}, StreamedExperience),
        "trusted": ({"reward_source": None, "reward_function": lambda params: 1.0},
                    LockstepExperience),
        "sac": ({"algorithm": "sac", "spec": EnvSpec(track="racecraft_oval",
                                                     action_space=CONTINUOUS)},
                LockstepExperience),
        "lidar": ({"spec": lidar}, LockstepExperience),
    }  # fmt: skip
    for name, (overrides, kind) in cases.items():
        config = _config(redis_url, settings.REDIS_PREFIX, **overrides)
        source = config.rollouts.experience(experience_request(config))
        try:
            assert type(source) is kind, name
        finally:
            source.close()
