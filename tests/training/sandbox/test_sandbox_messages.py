"""Every message from a sandbox is checked before use: forged but well-formed messages (valid
frames, wrong contents) become the "sent malformed data" error, never an exception in the
validation or the trainer."""

from __future__ import annotations

import uuid

import numpy as np
import pytest
from django.conf import settings

from tests.training.sandbox.sandbox_support import host_intact, real_params
from training.rollout.streamed import StreamedExperience
from training.rollout.streams import Session, StreamError
from training.rollout.vecenv import RolloutError, _WorkerVecEnv
from training.sandbox import SandboxLimits, evaluate_reward
from training.sandbox.protocol import decode, encode

LIMITS = SandboxLimits(per_call_seconds=2.0, cpu_seconds=30)
#: Python guards off: the reward reaches its own channel (the worst case) and sends VALUE.
FORGER = """import gc
from training.sandbox.protocol import write_message

def context():
    for o in gc.get_objects():
        if type(o).__name__ == 'SandboxContext':
            return o

def reward_function(params):
    ctx = context()
    {action}
    return 1.0
"""

FORGED_REWARDS = {
    "index_out_of_range": "ctx.send({'i': 7, 'value': 1.0})",
    "negative_index": "ctx.send({'i': -1, 'value': 1.0})",
    "bool_index": "ctx.send({'i': True, 'value': 1.0})",
    "nan_reward": "ctx.send({'i': 0, 'value': float('nan')})",
    "huge_reward": "ctx.send({'i': 0, 'value': 1e300})",
    "string_reward": "ctx.send({'i': 0, 'value': '1.0'})",
    "missing_value": "ctx.send({'i': 0})",
    "not_an_object": "ctx.send([1, 2, 3])",
    "array_reward": "import numpy\n    ctx.send({'i': 0, 'value': numpy.ones(3)})",
    "error_not_an_object": "ctx.send({'i': 0, 'error': 'boom'})",
    "unknown_kind": "write_message(ctx._out, {'kind': 'surprise'})",
    "ready_again": "write_message(ctx._out, {'kind': 'locked', 'layers': {}})",
    "result_early": "write_message(ctx._out, {'kind': 'result', 'value': None, 'output': 7})",
}


@pytest.mark.parametrize("action", FORGED_REWARDS.values(), ids=list(FORGED_REWARDS))
def test_forged_validation_messages_are_malformed_data(action: str) -> None:
    source = FORGER.format(action=action)
    with host_intact():
        result = evaluate_reward(source, [real_params()], limits=LIMITS, python_guards=False)
    outcome = result.outcomes[0]
    assert outcome.value is None and outcome.error is not None
    assert "sent malformed data" in outcome.error.message


class FakeWorkers(_WorkerVecEnv):
    """Two envs on one "worker" whose replies are given, after a trip through the protocol."""

    def __init__(self, replies: list[object]) -> None:
        from gymnasium import spaces

        obs = spaces.Box(0, 255, (4, 4, 1), np.uint8)
        super().__init__(2, obs, spaces.Discrete(3))
        self.sizes = [2]
        self.replies = [decode(encode(r)[4:]) for r in replies]

    def _exchange(self, messages: list[dict]) -> list[dict]:
        return [self.replies.pop(0)]

    def close(self) -> None:
        pass


def _step(**changes: object) -> dict:
    info = {"status": "in_progress", "progress": 1.0, "lap": 1, "trace": [0, 1, 1.5, "x"]}
    reply = {
        "obs": np.zeros((2, 4, 4, 1), np.uint8),
        "rewards": np.ones(2, np.float32),
        "dones": np.zeros(2, bool),
        "infos": [dict(info), dict(info)],
    }
    reply.update(changes)
    return reply


GOOD_INFO = {"status": "in_progress", "progress": 1.0, "lap": 1, "trace": None}
FORGED_STEPS = {
    "obs_dtype": _step(obs=np.zeros((2, 4, 4, 1), np.float32)),
    "obs_shape": _step(obs=np.zeros((3, 4, 4, 1), np.uint8)),
    "obs_list": _step(obs=[[0]]),
    "rewards_nan": _step(rewards=np.array([1.0, np.nan], np.float32)),
    "rewards_inf": _step(rewards=np.array([np.inf, 1.0], np.float32)),
    "rewards_huge": _step(rewards=np.array([1e9, 1.0], np.float32)),
    "rewards_dtype": _step(rewards=np.ones(2, np.float64)),
    "rewards_shape": _step(rewards=np.ones(3, np.float32)),
    "dones_int": _step(dones=np.zeros(2, np.int64)),
    "infos_short": _step(infos=[GOOD_INFO]),
    "info_not_dict": _step(infos=[GOOD_INFO, "x"]),
    "info_extra_key": _step(infos=[GOOD_INFO, dict(GOOD_INFO, evil=1)]),
    "info_progress_nan": _step(infos=[GOOD_INFO, dict(GOOD_INFO, progress=float("nan"))]),
    "info_status_number": _step(infos=[GOOD_INFO, dict(GOOD_INFO, status=3)]),
    "info_trace_nested": _step(infos=[GOOD_INFO, dict(GOOD_INFO, trace=[[1, [2]]])]),
    "terminal_obs_shape": _step(
        infos=[GOOD_INFO, dict(GOOD_INFO, terminal_observation=np.zeros((2, 2), np.uint8))]
    ),
    "episode_entry_nested": _step(infos=[GOOD_INFO, dict(GOOD_INFO, episode_entry={"steps": [1]})]),
    "frame_not_jpeg": _step(
        infos=[
            dict(GOOD_INFO, frame={"camera": "x", "chase": "y", "progress": 1, "lap": 1}),
            GOOD_INFO,
        ]
    ),  # fmt: skip
    "not_a_dict": [1, 2],
}


def test_a_good_step_passes() -> None:
    env = FakeWorkers([_step()])
    env.step_async(np.zeros(2, np.int64))
    obs, rewards, dones, infos = env.step_wait()
    assert obs.shape == (2, 4, 4, 1) and rewards.tolist() == [1.0, 1.0] and len(infos) == 2


@pytest.mark.parametrize("reply", FORGED_STEPS.values(), ids=list(FORGED_STEPS))
def test_forged_rollout_steps_are_malformed_data(reply: object) -> None:
    env = FakeWorkers([reply])
    env.step_async(np.zeros(2, np.int64))
    with pytest.raises(RolloutError, match="sent malformed data"):
        env.step_wait()


def _drive(steps: int = 3, **changes: object) -> dict:
    """A worker's reply to ``drive``: ``steps`` steps of its two envs."""
    reply = {
        "rewards": np.ones((steps, 2), np.float32),
        "dones": np.zeros((steps, 2), bool),
        "infos": [[dict(GOOD_INFO), dict(GOOD_INFO)] for _ in range(steps)],
    }
    reply.update(changes)
    return reply


FORGED_DRIVES = {
    "more_steps_than_asked": _drive(5),
    "rewards_shape": _drive(rewards=np.ones((2, 2), np.float32)),
    "rewards_flat": _drive(rewards=np.ones(6, np.float32)),
    "rewards_nan": _drive(rewards=np.full((3, 2), np.nan, np.float32)),
    "rewards_huge": _drive(rewards=np.full((3, 2), 1e9, np.float32)),
    "dones_int": _drive(dones=np.zeros((3, 2), np.int64)),
    "infos_not_a_list": _drive(infos={"a": 1}),
    "a_step_short_of_envs": _drive(infos=[[GOOD_INFO, GOOD_INFO], [GOOD_INFO], [GOOD_INFO] * 2]),
    "info_extra_key": _drive(infos=[[GOOD_INFO, dict(GOOD_INFO, evil=1)]] * 3),
    "not_a_dict": [1, 2],
}


def test_a_good_drive_passes() -> None:
    env = FakeWorkers([_drive(2)])
    env.send_drive(None, 4)
    steps = env.receive_drive()
    assert len(steps) == 2 and steps[0][0].tolist() == [1.0, 1.0] and len(steps[0][2]) == 2


@pytest.mark.parametrize("reply", FORGED_DRIVES.values(), ids=list(FORGED_DRIVES))
def test_forged_drive_replies_are_malformed_data(reply: object) -> None:
    """What a worker says it drove (an evaluation driven in the worker) is checked as a
    step's reply is, and it may not say it drove more steps than it was asked for."""
    env = FakeWorkers([reply])
    env.send_drive(None, 4 if reply is FORGED_DRIVES["more_steps_than_asked"] else 3)
    with pytest.raises(RolloutError, match="sent malformed data"):
        env.receive_drive()


def _sample(steps: int = 3, **changes: object) -> dict:
    """A worker's reply to ``sample``: ``steps`` steps of its two envs, actions it drew."""
    reply = {
        "obs": np.zeros((steps, 2, 4, 4, 1), np.uint8),
        "actions": np.ones((steps, 2), np.int64),
        "rewards": np.ones((steps, 2), np.float32),
        "dones": np.zeros((steps, 2), bool),
        "infos": [[dict(GOOD_INFO), dict(GOOD_INFO)] for _ in range(steps)],
        "next_obs": np.zeros((2, 4, 4, 1), np.uint8),
    }
    reply.update(changes)
    return reply


FORGED_SAMPLES = {
    "fewer_steps_than_asked": _sample(2),
    "more_steps_than_asked": _sample(4),
    "action_out_of_the_space": _sample(actions=np.full((3, 2), 3, np.int64)),
    "action_negative": _sample(actions=np.full((3, 2), -1, np.int64)),
    "actions_float": _sample(actions=np.ones((3, 2), np.float64)),
    "actions_shape": _sample(actions=np.ones((3, 3), np.int64)),
    "obs_dtype": _sample(obs=np.zeros((3, 2, 4, 4, 1), np.float32)),
    "obs_shape": _sample(obs=np.zeros((3, 2, 4, 5, 1), np.uint8)),
    "obs_flat": _sample(obs=np.zeros((6, 4, 4, 1), np.uint8)),
    "next_obs_missing": _sample(next_obs=None),
    "rewards_nan": _sample(rewards=np.full((3, 2), np.nan, np.float32)),
    "dones_int": _sample(dones=np.zeros((3, 2), np.int64)),
    "infos_short": _sample(infos=[[GOOD_INFO, GOOD_INFO]] * 2),
    "info_extra_key": _sample(infos=[[GOOD_INFO, dict(GOOD_INFO, evil=1)]] * 3),
    "not_a_dict": [1, 2],
}


def test_a_good_sample_passes() -> None:
    env = FakeWorkers([_sample()])
    env.send_sample(None, 3)
    part = env.receive_sample()
    assert part.obs.shape == (3, 2, 4, 4, 1) and part.actions.tolist() == [[1, 1]] * 3
    assert part.next_obs.shape == (2, 4, 4, 1) and len(part.infos) == 3


@pytest.mark.parametrize("reply", FORGED_SAMPLES.values(), ids=list(FORGED_SAMPLES))
def test_forged_sample_replies_are_malformed_data(reply: object) -> None:
    """A rollout the workers drove is checked before it reaches the update: exactly the steps
    asked for, and every action one of the action space's (a worker chooses them)."""
    env = FakeWorkers([reply])
    env.send_sample(None, 3)
    with pytest.raises(RolloutError, match="sent malformed data"):
        env.receive_sample()


@pytest.mark.parametrize(
    "reply", [{"obs": np.zeros((2, 4, 4, 1), np.int8)}, {}, "obs"], ids=["dtype", "empty", "text"]
)
def test_forged_reset_replies_are_malformed_data(reply: object) -> None:
    with pytest.raises(RolloutError, match="sent malformed data"):
        FakeWorkers([reply]).reset()


@pytest.mark.parametrize(
    "body",
    [b"garbage", encode([1])[4:], encode({"kind": 3})[4:], encode({"x": 1})[4:]],
    ids=["bytes", "list", "kind_not_text", "no_kind"],
)
def test_forged_stream_messages_are_a_clear_error(body: bytes, redis_url: str) -> None:
    """What reaches the trainer's experience stream is decoded checked: a forged message ends
    the run with a clear error, never an exception of the decoder."""
    session = Session(redis_url, settings.REDIS_PREFIX, uuid.uuid4().hex)
    session.create()
    try:
        session.r.xadd(session.keys.exp, {"m": body})
        [(_entry, msg)] = list(session.read("trainer", block_ms=1000))
        assert isinstance(msg, StreamError)
        with pytest.raises(RolloutError, match="stream message"):
            StreamedExperience._take(None, msg, 0, 4)  # type: ignore[arg-type]
        forged_error = {"kind": "error", "message": {"x": 1}}
        with pytest.raises(RolloutError, match="x"):
            StreamedExperience._take(None, forged_error, 0, 4)  # type: ignore[arg-type]
    finally:
        session.cleanup()
        session.close()


def test_a_trace_row_may_carry_a_continuous_action_pair_and_nothing_deeper() -> None:
    from training.rollout.vecenv import _check_trace
    from training.sandbox.checked import Malformed

    _check_trace([1, 2, 0.5, 1.0, 0.1, 3, [12.5, 1.7], 0.3])  # continuous: (steering, speed)
    _check_trace([1, 2, 0.5, 1.0, 0.1, 3, 4, 0.3])  # discrete: the action's index
    for forged in ([[1, [2]]], [[1, 2, 3]], [[1], [2]], "row", [float("nan")]):
        with pytest.raises(Malformed):
            _check_trace(forged)
