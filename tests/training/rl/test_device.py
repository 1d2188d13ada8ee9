"""The trainer's torch device: ``auto`` takes the GPU when there is one (here: the CPU), a
named device must exist, and models build and load on the device asked for (CPU by default,
as evaluation, imports and the simulation side use them)."""

from __future__ import annotations

import io

import pytest
import torch

from training.rl.algorithms import DeviceError, build_model, load_model, resolve_device
from training.rl.hyperparams import Hyperparameters
from training.rl.runner import TrainingConfig, TrainingLoop
from training.rollout.envs import EnvSpec
from training.rollout.vecenv import LocalVecEnv

DISCRETE = [{"steering_angle": a, "speed": 1.0} for a in (-30, 0, 30)]
NO_GPU = not torch.cuda.is_available()


def test_auto_is_the_gpu_when_torch_sees_one_else_the_cpu() -> None:
    expected = "cuda" if torch.cuda.is_available() else "cpu"
    assert resolve_device("auto").type == expected
    assert resolve_device("").type == expected  # unset is auto
    assert resolve_device(" CPU ") == torch.device("cpu")


@pytest.mark.parametrize("name", ["gpu", "cuda:x", "cpu please"])
def test_a_misspelt_device_is_a_clear_error(name) -> None:
    with pytest.raises(DeviceError, match="is not a torch device: use auto, cpu, cuda"):
        resolve_device(name)


@pytest.mark.skipif(not NO_GPU, reason="this machine has a GPU")
@pytest.mark.parametrize("name", ["cuda", "cuda:0"])
def test_a_gpu_asked_for_by_name_must_exist(name) -> None:
    with pytest.raises(DeviceError, match="this machine has no CUDA GPU"):
        resolve_device(name)


def test_models_build_and_load_on_the_device_asked_for() -> None:
    env = LocalVecEnv(EnvSpec(track="racecraft_oval", action_space=DISCRETE), 1, None)
    try:
        hp = Hyperparameters(batch_size=32, num_epochs=3)
        model = build_model("clipped_ppo", env, hp, device=resolve_device("cpu"))
        assert model.device == torch.device("cpu")
        assert {p.device.type for p in model.policy.parameters()} == {"cpu"}
        buffer = io.BytesIO()
        model.save(buffer)
        again = load_model("clipped_ppo", buffer.getvalue(), env, hp)  # the CPU by default
        assert again.device == torch.device("cpu")
        for a, b in zip(model.policy.parameters(), again.policy.parameters(), strict=True):
            assert torch.equal(a, b)
    finally:
        env.close()


def test_a_bad_device_stops_training_before_any_worker_starts(monkeypatch) -> None:
    started = []
    monkeypatch.setattr(LocalVecEnv, "__init__", lambda *a, **k: started.append(a))
    config = TrainingConfig(
        spec=EnvSpec(track="racecraft_oval", action_space=DISCRETE), device="tpu-ish"
    )
    with pytest.raises(DeviceError, match="'tpu-ish' is not a torch device"):
        TrainingLoop(config)
    assert started == []
