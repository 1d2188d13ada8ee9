"""The rollout worker's own module stays light: a sandboxed worker that imported the trainer's
torch and stable-baselines3 took about 3.5 s more to start (issue 14)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from training.rollout.vecenv import WORKER_MAIN, WORKER_PREPARE

ROOT = Path(__file__).resolve().parents[3]


def test_the_worker_side_imports_neither_torch_nor_stable_baselines3() -> None:
    module = WORKER_MAIN.split(":")[0]
    assert WORKER_PREPARE.split(":")[0] == module
    probe = (
        f"import sys, {module}, training.sandbox.child\n"
        "print(','.join(m for m in ('torch', 'stable_baselines3', 'django') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, capture_output=True,
                         text=True, timeout=120, check=True)  # fmt: skip
    assert out.stdout.strip() == ""


def test_the_worker_entry_points_exist() -> None:
    import importlib

    for ref in (WORKER_MAIN, WORKER_PREPARE):
        module, name = ref.split(":")
        assert callable(getattr(importlib.import_module(module), name))


def test_live_frames_come_from_a_worker_without_landlock() -> None:
    """Without Landlock, seccomp refuses every open() after lock-down, so whatever the live
    view needs is imported before it (the chase view's module was imported on the first frame,
    and the frames failed with PermissionError)."""
    from training.rollout.envs import EnvSpec
    from training.rollout.vecenv import ROLLOUT_LIMITS
    from training.sandbox.process import SandboxProcess

    spec = EnvSpec(track="racecraft_oval")
    worker = SandboxProcess(
        target=WORKER_MAIN, prepare=WORKER_PREPARE, limits=ROLLOUT_LIMITS,
        reward_source="def reward_function(params):\n    return 1.0\n",
        args={"spec": spec.to_json(), "num_envs": 1, "phase": "training", "first_env": 0},
        disabled_layers=("landlock",),
    )  # fmt: skip
    try:
        worker.launch()
        layers = worker.wait_started()
        assert layers["seccomp"] == "active (all opens refused: no Landlock)"
        worker.send({"cmd": "reset", "seeds": [0]})
        worker.recv(timeout=60)
        worker.send({"cmd": "step", "actions": [0], "frames": True})
        reply = worker.recv(timeout=60)
        assert reply.kind == "message", reply
        frame = reply.value["infos"][0]["frame"]
        assert len(frame["camera"]) > 100 and len(frame["chase"]) > 100  # JPEG bytes
    finally:
        worker.close()
