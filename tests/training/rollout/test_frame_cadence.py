"""Live frames keep a fixed 15 fps cadence, whatever the step time (issue 14)."""

from __future__ import annotations

import numpy as np

from training.rollout.envs import FRAME_INTERVAL_S, EnvRunner, EnvSpec, FrameGrabber


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


def test_a_restart_makes_the_next_frame_due_at_once() -> None:
    grabber = FrameGrabber(env=None)  # type: ignore[arg-type]
    assert grabber.due(100.0)
    assert not grabber.due(100.01)
    grabber.restart()  # a reset: a new episode
    assert grabber.due(100.02)
    assert not grabber.due(100.03)  # ... then the cadence again


def test_every_reset_shows_its_first_step_however_soon_it_comes() -> None:
    """An evaluation that leaves the track within a frame's interval of the lap before it
    (the spare lap) sent no frame at all, and the live view never showed it: each reset's
    first step sends one now. The interval is an hour here, so only the reset can make a
    frame due."""
    spec = EnvSpec(track="racecraft_oval")  # DeepRacer's default actions
    runner = EnvRunner([spec.make(lambda params: 1.0)])
    runner.want_frames = True
    runner.frames.interval_s = 3600.0
    try:
        for _ in range(3):
            runner.reset([0])
            _obs, _rewards, _dones, infos = runner.step(np.array([0]))
            assert "frame" in infos[0]
            _obs, _rewards, _dones, infos = runner.step(np.array([0]))
            assert "frame" not in infos[0]  # the cadence goes on within the episode
    finally:
        runner.close()
