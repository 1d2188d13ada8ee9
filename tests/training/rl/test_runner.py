"""The training loop on its own (no Django): DeepRacer iterations with PPO and SAC, sandboxed
rewards, checkpoints that load safely, stopping, and resuming from a checkpoint."""

from __future__ import annotations

import threading

import pytest

from training.rl.checkpoints import load_checkpoint
from training.rl.hyperparams import parse_hyperparameters
from training.rl.metadata import build_metadata
from training.rl.runner import TrainingConfig, TrainingHooks, train
from training.rollout.envs import EnvSpec

CONTINUOUS = {"steering_angle": {"low": -30, "high": 30}, "speed": {"low": 0.5, "high": 3.0}}
DISCRETE = [{"steering_angle": a, "speed": v} for a in (-30, 0, 30) for v in (1.0, 2.0)]
REWARD = """
def reward_function(params):
    return params["speed"] if params["all_wheels_on_track"] else 1e-3
"""
pytestmark = pytest.mark.slow


class Collect(TrainingHooks):
    def __init__(self, iterations: int) -> None:
        self.iterations = iterations
        self.results = []
        self.checkpoints = []
        self.rows = []
        self.episodes = []

    def on_episode(self, entry: dict) -> None:
        self.episodes.append(entry)

    def on_iteration(self, result, checkpoint, rows) -> None:
        self.results.append(result)
        self.checkpoints.append(checkpoint)
        self.rows.append(rows)

    def should_stop(self) -> bool:
        return len(self.results) >= self.iterations


@pytest.mark.parametrize(
    "algorithm, actions",
    [("clipped_ppo", DISCRETE), ("clipped_ppo", CONTINUOUS), ("sac", CONTINUOUS)],
)
def test_iterations_with_a_sandboxed_reward(algorithm, actions):
    hooks = Collect(iterations=2)
    config = TrainingConfig(
        spec=EnvSpec(track="racecraft_summit", action_space=actions),  # narrow: short episodes
        algorithm=algorithm,
        hyperparameters=parse_hyperparameters(
            {"num_episodes_between_training": 8, "num_epochs": 3, "batch_size": 32}, algorithm
        ),
        max_minutes=60,  # the hooks stop it after 2 iterations, however loaded the machine is
        reward_source=REWARD,
        num_envs=2,
        eval_episodes=2,
    )
    summary = train(config, hooks)
    assert summary.stopped_by == "user" and summary.iterations == 2
    first = hooks.results[0]
    assert first.iteration == 1 and first.steps > 0 and first.episodes >= 1
    assert 0.0 <= first.eval_progress <= 100.0 and len(first.evaluation.progress) == 2
    assert hooks.results[0].best  # the first iteration is the best so far
    # the 19 sim-trace values, then the id of the car that drove the step
    assert all(len(row) == 20 for row in hooks.rows[0])
    assert len({row[-1] for row in hooks.rows[0]}) == 2
    assert {"reward_score", "completion_percentage", "episode_status"} <= set(hooks.episodes[0])
    metadata = build_metadata(action_space=actions, training_algorithm=algorithm,
                              sensor=["FRONT_FACING_CAMERA"],
                              neural_network="RACECRAFT_LEAN_CNN")  # fmt: skip
    model = load_checkpoint(hooks.checkpoints[-1], metadata)  # nothing unpickled
    assert model.num_timesteps == hooks.results[-1].total_steps


def test_training_resumes_from_a_checkpoint():
    spec = EnvSpec(track="racecraft_oval", action_space=DISCRETE)
    hp = parse_hyperparameters({"num_episodes_between_training": 4, "num_epochs": 3})
    common = {"spec": spec, "hyperparameters": hp, "reward_source": REWARD, "num_envs": 4,
              "eval_episodes": 1}  # fmt: skip
    first = Collect(iterations=1)
    train(TrainingConfig(**common), first)
    again = Collect(iterations=1)
    train(TrainingConfig(**common, initial_checkpoint=first.checkpoints[0]), again)
    assert again.results[0].total_steps > first.results[0].total_steps  # steps carried on


class Watch(Collect):
    """Collects live frames, and how many iterations had ended when each came."""

    def __init__(self, iterations: int) -> None:
        super().__init__(iterations)
        self.frames: list[tuple[int, dict]] = []

    def frames_wanted(self) -> bool:
        return True

    def on_frame(self, frame: dict) -> None:
        self.frames.append((len(self.results), frame))


def one_short_iteration() -> TrainingConfig:
    """PPO on 2 cars, 4 episodes an update, one evaluation episode (the hooks stop it)."""
    return TrainingConfig(
        spec=EnvSpec(track="racecraft_summit", action_space=DISCRETE),
        hyperparameters=parse_hyperparameters(
            {"num_episodes_between_training": 4, "num_epochs": 3, "batch_size": 32}, "clipped_ppo"
        ),
        max_minutes=60,
        reward_source=REWARD,
        num_envs=2,
        eval_episodes=1,
    )


def test_the_live_view_shows_training_episodes_and_evaluation_laps():
    """In lockstep the evaluation lap feeds the live view too, each frame saying what it
    shows."""
    hooks = Watch(iterations=1)
    train(one_short_iteration(), hooks)
    phases = {frame["phase"] for _, frame in hooks.frames}
    assert phases == {"training", "evaluation"}
    assert all(frame["iteration"] == 1 for _, frame in hooks.frames)
    # Before the iteration ended, but for the spare lap that goes on while it is logged.
    assert all(ended == 0 for ended, frame in hooks.frames if not frame.get("spare"))
    for _, frame in hooks.frames:
        assert frame["camera"][:2].tobytes() == b"\xff\xd8"  # JPEG
    scored = [i for i, (_, f) in enumerate(hooks.frames) if f["phase"] == "evaluation"]
    trained = [i for i, (_, f) in enumerate(hooks.frames) if f["phase"] == "training"]
    assert scored and trained and max(trained) < min(scored)  # the evaluation after the rollout


def test_the_live_view_goes_on_while_the_policy_updates(monkeypatch):
    """Between the rollout and the evaluation a frozen copy of the policy drives the
    evaluation env for the live view. The update here waits (60 s at most) until such a frame
    came, so the test does not depend on how long an update takes."""
    from training.rl import algorithms

    hooks = Watch(iterations=1)
    spare_seen = threading.Event()
    original_on_frame = hooks.on_frame

    def on_frame(frame: dict) -> None:
        original_on_frame(frame)
        if frame.get("spare"):
            spare_seen.set()

    hooks.on_frame = on_frame
    original_train = algorithms.DeepRacerPPO.train
    waited: list[bool] = []

    def train_after_a_spare_frame(self) -> None:
        if not waited:  # the second update, which the evaluation's end stops, does not wait
            waited.append(spare_seen.wait(timeout=60))
        original_train(self)

    monkeypatch.setattr(algorithms.DeepRacerPPO, "train", train_after_a_spare_frame)
    train(one_short_iteration(), hooks)
    assert waited == [True]
    spare = [f for _, f in hooks.frames if f.get("spare")]
    assert spare and all(f["phase"] == "evaluation" and f["iteration"] == 1 for f in spare)
    # The order a viewer sees: training episodes, the spare lap, then the scored evaluation.
    phases = [("spare" if f.get("spare") else f["phase"]) for _, f in hooks.frames]
    first_spare = phases.index("spare")
    assert set(phases[:first_spare]) == {"training"}
    assert "evaluation" in phases[first_spare:]


@pytest.mark.parametrize("drive_steps", [1, None], ids=["a_step_a_command", "chunks"])
def test_an_evaluation_beside_the_next_rollout_learns_and_scores_the_same(monkeypatch,
                                                                          drive_steps):  # fmt: skip
    """PPO's evaluation runs beside the next rollout (its policy is the one that rollout
    drives with): every iteration's steps, evaluation and weights are what evaluating first
    gives. The hooks stop each run after 3 iterations; the third evaluation of the
    overlapped run ended inside the fourth rollout, which is not learnt from. The envs' side
    drives the evaluation (the lean networks travel to it), a chunk of steps a command; one
    step a command spreads it over the rollout and the update, as a slow simulation would."""
    import dataclasses

    import torch

    from training.rollout import lockstep
    from training.rollout.backends import LocalRollouts
    from training.rollout.lockstep import Evaluation, LockstepExperience

    if drive_steps is not None:
        monkeypatch.setattr(lockstep, "DRIVE_STEPS", drive_steps)

    beside_steps = []
    advance = LockstepExperience.advance_evaluation

    def counted(source, learner):
        beside_steps[-1] += source.evaluating is not None
        advance(source, learner)

    monkeypatch.setattr(LockstepExperience, "advance_evaluation", counted)
    beside_update = []  # evaluation steps driven on the spectator's thread, during updates
    receive = Evaluation.receive

    def received(evaluation, hooks):
        assert evaluation.driven_by_workers
        before = evaluation.busy_s
        receive(evaluation, hooks)
        assert evaluation.busy_s >= before
        beside_update[-1] += threading.current_thread().name == "spectator"

    monkeypatch.setattr(Evaluation, "receive", received)
    runs = {}
    for overlap in (False, True):
        beside_steps.append(0)
        beside_update.append(0)
        hooks = Collect(iterations=3)
        config = dataclasses.replace(
            one_short_iteration(), seed=5, eval_episodes=2,
            rollouts=LocalRollouts(num_workers=2, overlap_evaluation=overlap),
        )  # fmt: skip
        summary = train(config, hooks)
        assert summary.stopped_by == "user" and summary.iterations == 3
        runs[overlap] = hooks
    assert beside_steps[0] == 0 and beside_steps[1] > 0  # evaluation steps during rollouts
    assert beside_update[0] == 0
    if drive_steps == 1:
        assert beside_steps[1] > 10 and beside_update[1] > 10  # and during updates
    before, beside = runs[False], runs[True]
    for a, b in zip(before.results, beside.results, strict=True):
        assert (a.iteration, a.steps, a.total_steps) == (b.iteration, b.steps, b.total_steps)
        assert a.evaluation == b.evaluation  # progress, statuses, laps, rewards: all of it
        assert a.train_reward == b.train_reward
    metadata = build_metadata(action_space=DISCRETE, neural_network="RACECRAFT_LEAN_CNN")
    for a, b in zip(before.checkpoints, beside.checkpoints, strict=True):
        weights_a = load_checkpoint(a, metadata).policy.state_dict()
        weights_b = load_checkpoint(b, metadata).policy.state_dict()
        assert all(torch.equal(weights_a[k], weights_b[k]) for k in weights_a)  # bit for bit
    assert [len(r) for r in before.rows] == [len(r) for r in beside.rows]


class Beside:
    """Patches for a run whose evaluations go on beside the next update (nobody watches): each
    update waits (60 s at most) until the evaluation handed to it has been driven to its end,
    so that the test does not depend on how long an update takes; records the updates. The
    evaluation's envs drive one step a command, and the trainer takes one up only after each
    chunk of a sampled rollout (not while it waits for the chunk), so that it outlasts the
    rollout beside it here, as it does a fast rollout on a loaded machine."""

    def __init__(self, monkeypatch) -> None:
        from training.rl import algorithms
        from training.rollout import lockstep
        from training.rollout.lockstep import LockstepExperience, Spectator

        monkeypatch.setattr(lockstep, "DRIVE_STEPS", 1)
        monkeypatch.setattr(LockstepExperience, "_wait_for_workers", lambda source, learner: None)

        self.driven = threading.Event()
        self.handed = False
        self.in_update = False
        self.waited: list[bool] = []
        self.epochs: list[int] = []
        run, rollout_ended = Spectator._run, LockstepExperience.rollout_ended
        update = algorithms.DeepRacerPPO.train

        def driven(spectator, *args, **kwargs):
            run(spectator, *args, **kwargs)  # nobody watches: it ends with the evaluation
            self.driven.set()

        def ended(source, learner):
            self.driven.clear()
            self.handed = source.evaluating is not None
            rollout_ended(source, learner)

        def train(model):
            if self.handed:
                self.waited.append(self.driven.wait(timeout=60))
            self.in_update = True
            try:
                update(model)
            finally:
                self.in_update = False
                self.epochs.append(model._n_updates)

        monkeypatch.setattr(Spectator, "_run", driven)
        monkeypatch.setattr(LockstepExperience, "rollout_ended", ended)
        monkeypatch.setattr(algorithms.DeepRacerPPO, "train", train)


def test_an_evaluation_longer_than_the_rollout_goes_back_during_the_next_update(monkeypatch):
    """What is left of an evaluation at the rollout's end is driven on the spectator's thread
    beside the next update; its outcome goes back between two of the update's minibatches,
    and the stop it brings ends that update there (not learnt from: the run keeps 1 iteration)."""
    beside = Beside(monkeypatch)
    came_in_update: list[bool] = []

    class Hooks(Collect):
        def on_iteration(self, result, checkpoint, rows) -> None:
            came_in_update.append(beside.in_update)
            super().on_iteration(result, checkpoint, rows)

    hooks = Hooks(iterations=1)
    config = one_short_iteration()
    config.eval_laps = 2  # two laps from the start line: longer than the next rollout
    summary = train(config, hooks)
    assert beside.waited == [True]  # the second update had the evaluation beside it
    assert came_in_update == [True]  # and its outcome came during that update
    assert summary.iterations == 1 and summary.stopped_by == "user"
    # The first update ran its 3 epochs; the second stopped in its first epoch.
    assert beside.epochs[0] == 3 and beside.epochs[1] == 4
    assert not [t for t in threading.enumerate() if t.name == "spectator"]


def test_an_error_in_an_evaluation_beside_the_update_stops_the_run(monkeypatch):
    """A simulation worker that fails while the evaluation runs beside the update fails the
    run with its message, as it would in the trainer's own thread; nothing is left running."""
    from training.rollout.lockstep import Evaluation
    from training.rollout.vecenv import RolloutError

    Beside(monkeypatch)
    receive = Evaluation.receive

    def receive_or_fail(evaluation, hooks):
        if threading.current_thread().name == "spectator":
            raise RolloutError("a simulation worker stopped unexpectedly")
        receive(evaluation, hooks)

    monkeypatch.setattr(Evaluation, "receive", receive_or_fail)
    config = one_short_iteration()
    config.eval_laps = 2
    with pytest.raises(RolloutError, match="stopped unexpectedly"):
        train(config, Collect(iterations=2))
    assert not [t for t in threading.enumerate() if t.name == "spectator"]
