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
