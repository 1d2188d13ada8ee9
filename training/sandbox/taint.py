"""Whether this process ever loaded a user's reward code.

A sandbox child marks itself just before it loads the user's module; from then on everything
in it (the simulator it hosts, the laps it reports) is the user's to change. Code that judges
laps for a leaderboard or a race calls :func:`refuse_if_tainted` first, so it can never run in
such a process, whatever else fails.
"""

from __future__ import annotations

_tainted = False


class TaintedProcess(RuntimeError):
    """Judging was asked of a process that ran user code."""


def mark() -> None:
    """Called by the sandbox child before it loads user code (never undone)."""
    global _tainted
    _tainted = True


def tainted() -> bool:
    return _tainted


def refuse_if_tainted(what: str) -> None:
    if _tainted:
        raise TaintedProcess(f"{what} cannot run in a process that loaded a reward function")
