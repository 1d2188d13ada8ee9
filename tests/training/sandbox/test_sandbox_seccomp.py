"""The seccomp filter is built by libseccomp for each architecture, holds its limits, and the
sandbox fails closed without it."""

from __future__ import annotations

import re

import pytest

from tests.training.sandbox.sandbox_support import real_params
from training.sandbox import SandboxLimits, evaluate_reward, seccomp

#: Syscall numbers from each architecture's unistd.h.
NUMBERS = {
    seccomp.SCMP_ARCH_X86_64: {"execve": 59, "socket": 41, "clone": 56, "kill": 62},
    seccomp.SCMP_ARCH_AARCH64: {"execve": 221, "socket": 198, "clone": 220, "kill": 129},
}
LIMITS = SandboxLimits(per_call_seconds=2.0, cpu_seconds=30)


@pytest.mark.parametrize("arch", list(NUMBERS), ids=["x86_64", "aarch64"])
def test_the_filter_is_built_for_each_architecture(arch: int) -> None:
    text = seccomp.filter_text(arch=arch)
    assert f"if ($arch == {arch})" in text
    for name, nr in NUMBERS[arch].items():
        assert re.search(rf'syscall "{name}" \({nr}\)', text), name
    assert "ERRNO(1)" in text
    # aarch64 has no open(2): openat carries the write-flag rules there.
    assert re.search(r'syscall "openat" \(\d+\)', text)


def test_without_libseccomp_the_layer_says_how_to_get_it(monkeypatch) -> None:
    monkeypatch.setattr(seccomp, "library", lambda: None)
    reason = seccomp.install_filter(allow_threads=False, deny_open=False)
    assert reason is not None and "apt-get install libseccomp2" in reason


def _run(body: str) -> str:
    source = f"import os, resource\n\ndef reward_function(params):\n    {body}\n    return 1.0\n"
    # Without namespaces the child is root of this machine: only seccomp stands in the way.
    result = evaluate_reward(
        source,
        [real_params()],
        limits=LIMITS,
        python_guards=False,
        disabled_layers=("namespaces",),
    )
    assert result.layers["seccomp"] == "active"
    (error,) = result.errors
    return error.message


def test_the_limits_cannot_be_raised_again() -> None:
    body = (
        "soft, hard = resource.getrlimit(resource.RLIMIT_CPU)\n"
        "    resource.setrlimit(resource.RLIMIT_CPU, (hard + 100, hard + 100))"
    )
    assert "not allowed to raise maximum limit" in _run(body)  # EPERM, as Python words it


def test_exec_is_refused() -> None:
    assert "PermissionError" in _run("os.execv('/bin/true', ['true'])")
