"""Django system checks: which reward-isolation layers this machine gives (``manage.py check``,
printed by ``manage.py up`` at start).

One sandbox is started with a trivial reward of ours (no user code) and its layer report is
turned into messages: an Info naming the active layers, a Warning for each layer that is
missing while others still give its protection, and an Error for each protection nothing
gives (a Warning instead when the operator set RACECRAFT_ALLOW_WEAK_SANDBOX). The report is
cached for the life of the process: the kernel does not change under it.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any

from django.conf import settings
from django.core.checks import CheckMessage, Error, Info, Warning, register

from training.sandbox import SandboxError, isolation_support, missing_requirements
from training.sandbox.requirements import LAYER_HELP, layer_active

TAG = "sandbox"
#: Layers worth a warning when missing even if others cover for them (defence in depth);
#: the pids cgroup and RLIMIT_NPROC stand in for each other (root vs. other users). Without
#: the io cgroup a child's reads that miss the page cache are not paced (seccomp only refuses
#: O_DIRECT).
CORE_LAYERS = (
    "namespaces", "rlimits", "no_new_privs", "landlock", "seccomp", "cgroup_memory", "cgroup_io",
)  # fmt: skip


@lru_cache(maxsize=1)
def _layers() -> tuple[tuple[str, str], ...] | str:
    try:
        return tuple(isolation_support().items())
    except SandboxError as exc:
        return str(exc)


def isolation_messages() -> list[CheckMessage]:
    """The check's messages for this machine (see the module docstring)."""
    layers = _layers()
    if isinstance(layers, str):
        return [
            Error(
                f"The reward sandbox cannot start on this machine: {layers}",
                hint="Reward functions cannot be validated or trained until it can.",
                id="racecraft.E010",
            )
        ]
    report = dict(layers)
    active = sorted(name for name in report if layer_active(report, name))
    out: list[CheckMessage] = [
        Info(f"Reward sandbox layers active: {', '.join(active)}.", id="racecraft.I010")
    ]
    missing = missing_requirements(report)
    uncovered = {p for r in missing for p in r.providers}
    for name in sorted(set(CORE_LAYERS) - set(active) - uncovered):
        out.append(
            Warning(
                f"Reward sandbox layer '{name}' is unavailable "
                f"({report.get(name, 'not reported')}); other layers still give its protection.",
                hint=f"For defence in depth provide {LAYER_HELP[name]}.",
                id="racecraft.W011",
            )
        )
    weak = settings.RACECRAFT_ALLOW_WEAK_SANDBOX
    for req in missing:
        how = "; or ".join(LAYER_HELP[p] for p in req.providers)
        text = f"Reward sandbox protection missing on this machine: {req.what}."
        if weak:
            out.append(
                Warning(
                    text + " Reward code runs anyway (RACECRAFT_ALLOW_WEAK_SANDBOX=1).",
                    hint=f"Provide {how}.",
                    id="racecraft.W012",
                )
            )
        else:
            out.append(
                Error(
                    text + " Validation and training will refuse to run reward code.",
                    hint=f"Provide {how}; or accept weaker isolation with "
                    "RACECRAFT_ALLOW_WEAK_SANDBOX=1.",
                    id="racecraft.E012",
                )
            )
    return out


@register(TAG)
def sandbox_isolation_check(app_configs: Any = None, **kwargs: Any) -> list[CheckMessage]:
    return isolation_messages()


def isolation_summary() -> list[str]:
    """The check's messages as lines for a terminal (``manage.py up``)."""
    messages = isolation_messages()
    return [f"{m.id} {m.msg}" + (f" HINT: {m.hint}" if m.hint else "") for m in messages]
