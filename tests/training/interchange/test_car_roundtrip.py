"""The car download comes back as the same model: export a model for the car, import that
archive as a new model, and both drive the same evaluation laps for the same seed."""

from __future__ import annotations

import pytest

from training.interchange.deepracer import import_deepracer_upload
from training.interchange.export import build_car_archive
from training.rl.checkpoints import load_checkpoint
from training.rl.evaluation import EvaluationSettings, evaluate, sb3_policy
from training.rollout.envs import EnvSpec

pytestmark = pytest.mark.slow


@pytest.mark.parametrize("fixture", ["ppo_discrete", "ppo_continuous"])
def test_exported_then_imported_model_drives_the_same_laps(fixture, request) -> None:
    tiny = request.getfixturevalue(fixture)
    imported = import_deepracer_upload(build_car_archive(tiny.metadata, tiny.model))
    again = load_checkpoint(imported.checkpoint_bytes, imported.metadata)
    spec = EnvSpec(track="racecraft_summit", action_space=tiny.metadata.actions.to_metadata())
    settings = EvaluationSettings(laps=3, record_video=False)
    original = evaluate(sb3_policy(tiny.model), spec, settings).to_json()
    roundtrip = evaluate(sb3_policy(again), spec, settings).to_json()
    assert original["laps"] and roundtrip["laps"] == original["laps"]
