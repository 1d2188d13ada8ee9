"""bench/bench_update.py runs every way of updating on a small rollout and ends with its
key=value line (the figures themselves are the bench's, never a test's)."""

from __future__ import annotations

import re
import sys

import torch

from tests.bench.loader import load_bench
from training.rl.policies import COMPACT, LEAN
from training.rl.presets import RACING


def test_every_way_updates_and_the_last_line_has_the_ratio(monkeypatch, capsys) -> None:
    with load_bench("bench_update") as bench:
        monkeypatch.setattr(sys, "argv", ["bench_update.py", "--steps", "64", "--repeats", "1",
                                          "--no-profile"])  # fmt: skip
        bench.main()
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.startswith("| ") and line[2:5] != "way"]
    assert [r.split(" | ")[0] for r in rows] == [
        "| SB3's path (before)", "| prepared images", "| + fused Adam",
        "| + channels-last convolutions (now, the lean network)",
        "| the compact network (RACECRAFT_COMPACT_CNN), the console's way",
    ]  # fmt: skip
    last = out.strip().splitlines()[-1]
    assert re.fullmatch(
        r"update_s=[\d.]+ lean_update_s=[\d.]+ baseline_update_s=[\d.]+ ratio=[\d.]+ "
        r"both_cores_update_s=[\d.]+ both_cores_ratio=[\d.]+ both_cores_same=[01]",
        last,
    )


def test_the_ways_are_what_they_say() -> None:
    with load_bench("bench_update") as bench:
        before, now = bench.make_model("baseline", "cpu"), bench.make_model("channels_last", "cpu")
        assert bench.console_way("cpu") == "channels_last"  # a GPU keeps the default layout
        assert bench.console_way("cuda") == bench.console_way("cuda:1") == "fused"
    assert before.prepare_images is False and now.prepare_images is True
    assert not before.policy.optimizer.param_groups[0].get("fused")
    assert now.policy.optimizer.param_groups[0]["fused"] is True
    conv = [m for m in now.policy.modules() if m.__class__.__name__ == "Conv2d"][1].weight
    old = [m for m in before.policy.modules() if m.__class__.__name__ == "Conv2d"][1].weight
    assert conv.is_contiguous(memory_format=torch.channels_last)
    assert old.is_contiguous()
    assert before.policy.features_extractor.network == LEAN


def test_the_compact_way_is_the_racing_presets_network_the_consoles_way() -> None:
    with load_bench("bench_update") as bench:
        compact = bench.make_model("channels_last", "cpu", RACING.network)
    extractor = compact.policy.features_extractor
    assert extractor.network == RACING.network == COMPACT
    assert compact.prepare_images is True
    assert compact.policy.optimizer.param_groups[0]["fused"] is True
