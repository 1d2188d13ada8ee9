"""bench/bench_video.py's bookkeeping, without a console: frames/s, the gaps (the window's end
included), encodes per frame and the last line."""

from __future__ import annotations

import pytest

from tests.bench.loader import load_bench


@pytest.fixture(scope="module")
def bench():
    with load_bench("bench_video") as module:
        yield module


def frames(times: list[float], phase: str = "evaluation") -> list[tuple[float, dict]]:
    return [(t, {"phase": phase, "iteration": 1, "version": 0}) for t in times]


def test_a_gap_over_a_second_is_reported_with_the_frames_around_it(bench) -> None:
    window = frames([100.0, 100.1, 100.2]) + frames([102.7, 102.8], phase="training")
    stats = bench.video_stats(window, 100.0, 103.0, received=[5, 5], counts={"encoded": 6})
    assert stats["frames"] == 5 and stats["fps"] == pytest.approx(5 / 3.0)
    assert stats["max_gap_s"] == pytest.approx(2.5)
    [(length, at, before, after)] = stats["long_gaps"]
    assert (length, at) == (pytest.approx(2.5), pytest.approx(0.2))
    assert (before["phase"], after["phase"]) == ("evaluation", "training")
    assert stats["encodes_per_frame"] == pytest.approx(6 / 5)


def test_frames_that_stop_before_the_window_ends_leave_a_gap(bench) -> None:
    stats = bench.video_stats(frames([0.0, 0.5]), 0.0, 4.0, received=[2], counts={})
    assert stats["max_gap_s"] == pytest.approx(3.5)
    assert stats["long_gaps"][0][3] == {"end": "window"}
    assert stats["encoded"] == 0 and stats["encodes_per_frame"] == 0.0


def test_the_last_line_is_the_streamed_mode_against_lockstep(bench) -> None:
    def result(mode: str, fps: float) -> dict:
        return {"mode": mode, "fps": fps, "max_gap_s": 0.4, "encodes_per_frame": 1.0,
                "window_s": 60.0}  # fmt: skip

    line = bench.last_line([result("lockstep", 2.0), result("streams", 13.0)])
    values = dict(pair.split("=") for pair in line.split())
    assert values["fps"] == "13.00" and values["ratio"] == "6.50"
    assert values["mode"] == "streams" and values["baseline_fps"] == "2.00"
    assert "encodes_per_frame" in values and "max_gap_s" in values
    assert bench.last_line([result("streams", 13.0)]).split()[3] == "ratio=0.00"


def test_a_whole_run_ends_with_its_training_time(bench) -> None:
    from datetime import UTC, datetime
    from types import SimpleNamespace

    job = SimpleNamespace(started_at=datetime.fromtimestamp(1_000.0, UTC), max_minutes=10)
    # Seen at wall time 1,300 (monotonic 50): training ends 300 s later, at monotonic 350.
    assert bench.training_end(job, 50.0, 1_300.0) == pytest.approx(350.0)
