"""The training loop's interface (issue 50): the loop asks a source for experience, has the
new policy evaluated, and ends the run; whatever the source does beside the update (lockstep:
the last evaluation) it says through the :class:`Experience` it gathered, and the loop calls
nothing else of it."""

from __future__ import annotations

import pytest

from training.rl import runner
from training.rl.runner import TrainingConfig, TrainingHooks
from training.rollout.envs import EnvSpec
from training.rollout.experience import EvaluationOutcome, Experience, ExperienceSource
from training.rollout.lockstep import LockstepExperience
from training.rollout.streamed import StreamedExperience

LOOP_CALLS = {"gather", "evaluate", "finish", "close"}


def test_the_source_protocol_is_what_the_loop_calls():
    members = {n for n in vars(ExperienceSource) if not n.startswith("_")}
    assert members == LOOP_CALLS
    for source in (LockstepExperience, StreamedExperience):
        assert set(vars(source)) >= LOOP_CALLS
        for gone in ("start", "poll", "after_update", "reserved_cores"):
            assert not hasattr(source, gone), (source.__name__, gone)


class Recorder(TrainingHooks):
    def __init__(self, iterations: int) -> None:
        self.iterations, self.results = iterations, []

    def on_iteration(self, result, checkpoint, rows) -> None:
        self.results.append(result)

    def should_stop(self) -> bool:
        return len(self.results) >= self.iterations


@pytest.mark.parametrize("spare", [0, 1])
def test_the_update_leaves_the_experiences_cores_and_calls_it_between_minibatches(
    monkeypatch, spare
):
    """A source with nothing but the four calls runs; each update leaves the cores its
    experience asks for and calls the experience back after each of its three minibatches,
    and each iteration's evaluation goes back when the next one is asked for."""
    calls: list[str] = []

    class Scripted:
        env = None

        def gather(self, learner) -> Experience:
            calls.append("gather")
            learner.model.num_timesteps += 1
            return Experience(steps=1, episodes=[], rows=[], rollout_s=0.0, spare_cores=spare,
                              between_minibatches=lambda: calls.append("minibatch"))  # fmt: skip

        def evaluate(self, learner, iteration: int) -> None:
            calls.append(f"evaluate {iteration}")
            learner.evaluated(iteration, EvaluationOutcome([10.0], ["off_track"], [[]], [0.0]),
                              0.0)  # fmt: skip

        def finish(self, learner) -> None:
            calls.append("finish")

        def close(self) -> None:
            calls.append("close")

    class Model:
        num_timesteps = 0
        between_minibatches = None

        def train(self) -> None:
            for _ in range(3):
                if self.between_minibatches is not None and self.between_minibatches():
                    break

        def set_logger(self, logger) -> None:
            pass

        def save(self, buffer) -> None:
            buffer.write(b"ckpt")

    class Backend:
        def experience(self, request):
            return Scripted()

    spares: list[int] = []
    update_threads = runner.update_threads

    def counted(threads: int, spare_cores: int) -> int:
        spares.append(spare_cores)
        return update_threads(threads, spare_cores)

    monkeypatch.setattr(runner, "build_model", lambda *args, **kwargs: Model())
    monkeypatch.setattr(runner, "update_threads", counted)
    hooks = Recorder(iterations=2)
    config = TrainingConfig(spec=EnvSpec(track="racecraft_oval"), rollouts=Backend())
    summary = runner.train(config, hooks)
    assert summary.iterations == 2 and [r.iteration for r in hooks.results] == [1, 2]
    update = ["gather", "minibatch", "minibatch", "minibatch"]
    assert calls == [*update, "evaluate 1", *update, "evaluate 2", "finish", "close"]
    assert spare in spares  # the update's threads: the experience's spare cores left
    assert set(spares) <= {0, spare}  # ... and no other (0: driving)
