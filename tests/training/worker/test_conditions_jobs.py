"""A training job of a model with the outside-world setting hands it to every rollout (its env
spec, also as a simulation worker's message on the queue); its evaluations stay clean."""

from __future__ import annotations

import json

import pytest

from training import services
from training.models import TrainingJob
from training.rl.runner import evaluation_spec
from training.worker import common
from training.worker import training as worker_training

pytestmark = [pytest.mark.django_db, pytest.mark.usefixtures("store_dir")]
ACTIONS = [{"steering_angle": a, "speed": 1.0} for a in (-30, 0, 30)]
REWARD = "def reward_function(params):\n    return 1.0\n"
WORLD = {"families": {"camera": {"noise": [0, 4]}, "latency": {}}}


def test_training_gets_the_setting_and_its_evaluations_do_not(alice, monkeypatch) -> None:
    model = services.model_create(owner=alice, name="outside", track_id="racecraft_oval",
                                  action_space=ACTIONS, reward_function=REWARD,
                                  validate_reward=False, conditions=WORLD)  # fmt: skip
    job = services.training_start(model=model, user=alice, enqueue=False)
    seen = []

    def train(config, hooks):  # what the loop would be given; stop there
        seen.append(config)
        raise RuntimeError("enough")

    monkeypatch.setattr(worker_training, "train", train)
    assert worker_training.run_training_job(job.pk, "test") == "failed"
    spec = seen[0].spec
    assert spec.conditions == model.conditions and spec.conditions_seed is None
    assert evaluation_spec(seen[0]).conditions == {}
    assert common.env_spec(model, track_id="racecraft_oval").conditions == {}  # an evaluation
    assert TrainingJob.objects.get(pk=job.pk).error.endswith("enough")
    # a simulation worker on another machine gets it in its message, as JSON
    sent = {}
    monkeypatch.setattr(common.dispatch, "send", lambda name, **kw: sent.update(kw) or "t")
    common.send_simulation(spec=spec.to_json(), eval_spec=evaluation_spec(seen[0]).to_json())
    message = json.loads(json.dumps(sent))
    assert message["spec"]["conditions"] == model.conditions
    assert message["eval_spec"]["conditions"] == {}
