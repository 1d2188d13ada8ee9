"""A sandbox target for test_sandbox_shared_limits.py: it calls the reward once per phase of
``ctx.args["phases"]`` (the reward takes what it can and keeps it in its module), sends what
the reward printed, and waits for the parent's word before the next phase, so the parent can
measure the host while the child holds its share."""

from __future__ import annotations

from typing import Any


def hold(ctx: Any) -> None:
    for phase in ctx.args["phases"]:
        ctx.reward({"phase": phase})
        ctx.send(ctx.take_output())
        if ctx.recv() is None:  # the parent closed the channel
            return
