"""Fail closed: a machine that cannot give a protection runs no reward code, and says what the
operator must provide; RACECRAFT_ALLOW_WEAK_SANDBOX runs it anyway, with a warning everywhere.

Missing layers are simulated with RACECRAFT_SANDBOX_SIMULATE_MISSING, which only changes the
child's report: the last test shows the real layers still hold under it.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from django.core.checks import ERROR, INFO, WARNING

from tests.training.sandbox.sandbox_support import TRACK_ID, host_intact, real_params
from training import checks
from training.rewards.validation import validate_reward_function
from training.rollout.envs import EnvSpec
from training.rollout.vecenv import SandboxedVecEnv
from training.sandbox import SandboxLimits, SandboxUnavailable, evaluate_reward
from training.sandbox.requirements import ALLOW_WEAK_ENV, REQUIREMENTS, SIMULATE_ENV

#: For each protection, layers whose absence leaves nothing to give it on this machine.
BREAKS = {
    "no_writes": "landlock,seccomp",
    "no_network": "namespaces,seccomp",
    "no_processes": "seccomp,cgroup_pids,nproc_limit",
    "no_limit_raise": "limits_locked",
    "no_signals": "seccomp,signal_scope",
    "no_scheduling": "seccomp,namespaces",
    "memory_bound": "cgroup_memory,address_space_limit",
    "no_host_watch": "seccomp",
    "io_bound": "cgroup_io,seccomp",
    "signals_bounded": "rlimits",
    "no_host_lookups": "mount_namespace",
}


def broken_by(layers: str) -> tuple[str, ...]:
    """The protections none of whose layers is left when ``layers`` are missing."""
    gone = set(layers.split(","))
    return tuple(r.name for r in REQUIREMENTS if set(r.providers) <= gone)


#: A module that never finishes loading: a refusal must come before it is loaded at all.
NEVER_LOADS = "while True:\n    pass\n\ndef reward_function(params):\n    return 1.0\n"
SLOW_LIMITS = SandboxLimits(per_call_seconds=120.0, cpu_seconds=300)
OK = "def reward_function(params):\n    return 1.0\n"


@pytest.fixture(autouse=True)
def _closed(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(ALLOW_WEAK_ENV, raising=False)
    monkeypatch.delenv(SIMULATE_ENV, raising=False)
    checks._layers.cache_clear()
    yield
    checks._layers.cache_clear()


def test_every_protection_has_a_simulation() -> None:
    assert set(BREAKS) == {r.name for r in REQUIREMENTS}


@pytest.mark.parametrize("requirement", REQUIREMENTS, ids=lambda r: r.name)
def test_validation_refuses_to_load_the_code(requirement, monkeypatch) -> None:
    monkeypatch.setenv(SIMULATE_ENV, BREAKS[requirement.name])
    with host_intact(), pytest.raises(SandboxUnavailable) as caught:
        evaluate_reward(NEVER_LOADS, [real_params()], limits=SLOW_LIMITS)
    assert caught.value.missing == broken_by(BREAKS[requirement.name])
    assert requirement.name in caught.value.missing
    result = validate_reward_function(OK, TRACK_ID)
    (error,) = result.errors
    assert requirement.what in error.message
    assert "RACECRAFT_ALLOW_WEAK_SANDBOX=1" in error.message
    assert "situation" not in error.message  # one operator message, not one per situation
    assert result.rewards == {}


@pytest.mark.parametrize("requirement", REQUIREMENTS, ids=lambda r: r.name)
def test_training_rollouts_refuse_to_load_the_code(requirement, monkeypatch) -> None:
    monkeypatch.setenv(SIMULATE_ENV, BREAKS[requirement.name])
    with host_intact(), pytest.raises(SandboxUnavailable) as caught:
        SandboxedVecEnv(EnvSpec(track=TRACK_ID), 1, NEVER_LOADS, num_workers=1)
    assert requirement.what in str(caught.value)
    assert "needs" in str(caught.value)  # how to get it


# seccomp alone is the wall for inotify and the page cache (issue 52): its absence fails closed.
@pytest.mark.parametrize("layer", ["cgroup_io", "landlock", "namespaces", "cgroup_pids"])
def test_one_missing_layer_is_covered_by_the_others(layer, monkeypatch) -> None:
    monkeypatch.setenv(SIMULATE_ENV, layer)
    result = evaluate_reward(OK, [real_params()])
    assert result.layers[layer].startswith("unavailable: simulated")
    assert [o.value for o in result.outcomes] == [1.0]
    assert result.weak == ()


def test_the_opt_in_runs_the_code_with_a_warning(monkeypatch) -> None:
    monkeypatch.setenv(SIMULATE_ENV, BREAKS["no_writes"])
    monkeypatch.setenv(ALLOW_WEAK_ENV, "1")
    result = validate_reward_function(OK, TRACK_ID)
    assert result.ok, result.errors
    assert result.rewards
    (warning,) = result.warnings
    assert "weakened isolation" in warning and "no_writes" in warning
    rollout = SandboxedVecEnv(EnvSpec(track=TRACK_ID), 1, OK, num_workers=1)
    try:
        assert rollout.workers[0].weak == broken_by(BREAKS["no_writes"])
    finally:
        rollout.close()


@pytest.mark.parametrize("value", ["0", "", "maybe"])
def test_anything_but_an_explicit_yes_keeps_it_closed(value, monkeypatch) -> None:
    monkeypatch.setenv(SIMULATE_ENV, BREAKS["no_network"])
    monkeypatch.setenv(ALLOW_WEAK_ENV, value)
    with pytest.raises(SandboxUnavailable):
        evaluate_reward(OK, [real_params()])


def test_the_simulation_never_weakens_a_real_layer(tmp_path: Path, monkeypatch) -> None:
    everything = ",".join(sorted({n for v in BREAKS.values() for n in v.split(",")}))
    monkeypatch.setenv(SIMULATE_ENV, everything)
    monkeypatch.setenv(ALLOW_WEAK_ENV, "1")
    canary = tmp_path / "canary"
    source = (
        "import os\n\ndef reward_function(params):\n"
        f"    open({str(canary)!r}, 'w').write('x')\n    return 1.0\n"
    )
    with host_intact(tmp_path):
        result = evaluate_reward(source, [real_params()], python_guards=False)
    assert len(result.weak) == len(REQUIREMENTS)
    (error,) = result.errors
    assert "PermissionError" in error.message
    assert not canary.exists()


def test_the_system_check_reports_the_layers(settings, monkeypatch) -> None:
    settings.RACECRAFT_ALLOW_WEAK_SANDBOX = False
    messages = checks.isolation_messages()
    assert messages[0].level == INFO and "seccomp" in messages[0].msg
    assert not [m for m in messages if m.level >= ERROR]
    monkeypatch.setenv(SIMULATE_ENV, BREAKS["no_network"])
    checks._layers.cache_clear()
    errors = [m for m in checks.isolation_messages() if m.level >= ERROR]
    assert len(errors) == len(broken_by(BREAKS["no_network"]))  # one per missing protection
    (error,) = [m for m in errors if "no network" in m.msg]
    assert error.id == "racecraft.E012"
    assert "namespaces" in error.hint and "RACECRAFT_ALLOW_WEAK_SANDBOX=1" in error.hint
    settings.RACECRAFT_ALLOW_WEAK_SANDBOX = True
    levels = {m.id: m.level for m in checks.isolation_messages()}
    assert levels["racecraft.W012"] == WARNING and "racecraft.E012" not in levels
    assert any("W012" in line for line in checks.isolation_summary())


@pytest.mark.django_db
@pytest.mark.parametrize("weak", [True, False])
def test_every_page_warns_when_isolation_is_weakened(weak, client, settings) -> None:
    settings.RACECRAFT_ALLOW_WEAK_SANDBOX = weak
    page = client.get("/").content.decode()
    assert ("Reward isolation is weakened" in page) is weak
