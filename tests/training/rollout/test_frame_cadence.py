"""Live frames keep a fixed 15 fps cadence, whatever the step time (issue 14)."""

from __future__ import annotations

from training.rollout.envs import FRAME_INTERVAL_S, FrameGrabber


def frames_over(step_s: float, seconds: float, *, start: float = 100.0) -> list[float]:
    """When ``FrameGrabber.due`` says yes for steps ``step_s`` apart (no env needed)."""
    grabber = FrameGrabber(env=None)  # type: ignore[arg-type]
    times, t = [], start
    while t < start + seconds:
        if grabber.due(t):
            times.append(t)
        t += step_s
    return times


def test_steps_of_40_ms_give_15_frames_a_second_not_12_5() -> None:
    # Counting from the last frame sent, a frame every other 40 ms step: 12.5 fps.
    times = frames_over(0.040, 10.0)
    assert abs(len(times) / 10.0 - 1 / FRAME_INTERVAL_S) <= 0.2
    gaps = [b - a for a, b in zip(times, times[1:], strict=False)]
    assert max(gaps) <= 0.080 + 1e-9  # never more than two steps apart


def test_fast_steps_never_exceed_15_frames_a_second() -> None:
    times = frames_over(0.001, 5.0)
    assert len(times) <= 5.0 / FRAME_INTERVAL_S + 1
    assert min(b - a for a, b in zip(times, times[1:], strict=False)) >= FRAME_INTERVAL_S - 2e-3


def test_after_a_pause_the_cadence_starts_again_without_a_burst() -> None:
    grabber = FrameGrabber(env=None)  # type: ignore[arg-type]
    assert grabber.due(100.0)
    assert grabber.due(100.0 + FRAME_INTERVAL_S)
    assert grabber.due(130.0)  # a 30 s update: the first step after it sends a frame
    assert not grabber.due(130.04)  # ... and the next waits a whole interval
    assert grabber.due(130.0 + FRAME_INTERVAL_S)
