"""Race rules: laps, failures, resets and penalties, judged step by step."""

from __future__ import annotations

import pytest

from racing.rules import (
    IMMOBILIZED_STEPS,
    REVERSED_STEPS,
    RaceRules,
    RaceTracker,
    Status,
)

DT = 1 / 15
LENGTH = 10.0


def tracker(**rules) -> RaceTracker:
    t = RaceTracker(RaceRules(**rules), LENGTH, closed=True)
    t.start(0.0)
    return t


def drive(t: RaceTracker, ds: float, steps: int, wheels: int = 4):
    s = t._last_s
    out = None
    for _ in range(steps):
        s = (s + ds) % LENGTH
        out = t.update(s=s, dt=DT, moved_m=abs(ds), wheels_on_track=wheels)
        if out.done or out.truncated:
            break
    return out


def test_a_lap_completes_at_100_percent_with_its_time():
    t = tracker()
    out = drive(t, 0.125, 200)  # 0.125 m is exact in binary: 80 steps make 10 m
    assert out.status is Status.LAP_COMPLETE and out.done
    assert t.progress == 100.0
    assert len(t.laps) == 1
    assert t.laps[0].time_s == pytest.approx(80 * DT)


def test_progress_wraps_across_the_start_line():
    t = RaceTracker(RaceRules(), LENGTH)
    t.start(9.5)  # start half a metre before the line
    t.update(s=9.9, dt=DT, moved_m=0.4, wheels_on_track=4)
    t.update(s=0.3, dt=DT, moved_m=0.4, wheels_on_track=4)
    assert t.progress == pytest.approx(8.0)


def test_three_laps_back_to_back():
    t = tracker(laps=3)
    out = drive(t, 0.25, 1000)
    assert out.status is Status.LAP_COMPLETE
    assert [lap.lap for lap in t.laps] == [1, 2, 3]
    assert [round(lap.time_s / DT) for lap in t.laps] == [40, 40, 40]


def test_off_track_ends_a_training_episode():
    t = tracker()
    drive(t, 0.1, 5)
    out = t.update(s=0.6, dt=DT, moved_m=0.1, wheels_on_track=0)
    assert out.status is Status.OFF_TRACK and out.done and not out.reset


def test_some_wheels_off_is_not_off_track():
    t = tracker()
    out = t.update(s=0.1, dt=DT, moved_m=0.1, wheels_on_track=1)
    assert out.status is Status.IN_PROGRESS


def test_reversed_after_15_steps_of_falling_progress():
    t = tracker()
    drive(t, 0.1, 30)
    out = drive(t, -0.05, REVERSED_STEPS - 1)
    assert out.status is Status.IN_PROGRESS
    out = drive(t, -0.05, 1)
    assert out.status is Status.REVERSED and out.done


def test_immobilized_after_15_still_steps():
    t = tracker()
    drive(t, 0.1, 3)
    out = drive(t, 0.0002, IMMOBILIZED_STEPS)
    assert out.status is Status.IMMOBILIZED and out.done


def test_resets_turn_failures_into_penalties_counted_in_the_lap_time():
    t = tracker(resets=2, off_track_penalty_s=2.0)
    drive(t, 0.1, 10)
    out = t.update(s=1.1, dt=DT, moved_m=0.1, wheels_on_track=0)
    assert out.reset and not out.done and out.penalty_s == 2.0
    t.respawned_at(1.1)
    out = drive(t, 0.1, 200)
    assert out.status is Status.LAP_COMPLETE
    lap = t.laps[0]
    assert lap.off_tracks == 1 and lap.resets == 1 and lap.penalty_s == 2.0
    assert lap.time_s == pytest.approx(2.0 + t.steps * DT)


def test_failure_with_no_resets_left_ends_the_episode():
    t = tracker(resets=1)
    assert t.update(s=0.1, dt=DT, moved_m=0.1, wheels_on_track=0).reset
    out = t.update(s=0.2, dt=DT, moved_m=0.1, wheels_on_track=0)
    assert out.done and out.status is Status.OFF_TRACK
    assert t.current_lap.off_tracks == 2


def test_time_up_truncates():
    t = tracker(max_steps=10)
    out = drive(t, 0.01, 20)
    assert out.status is Status.TIME_UP and out.truncated and not out.done
    t2 = tracker(time_limit_s=1.0)
    out = drive(t2, 0.01, 100)
    assert out.status is Status.TIME_UP and t2.steps == 15


def test_penalties_by_status():
    rules = RaceRules(off_track_penalty_s=2, crash_penalty_s=5)
    assert rules.penalty_for(Status.OFF_TRACK) == 2
    assert rules.penalty_for(Status.CRASHED) == 5
    assert rules.penalty_for(Status.REVERSED) == 2
    assert rules.penalty_for(Status.IMMOBILIZED) == 0


@pytest.mark.parametrize(
    "bad", [{"laps": 0}, {"resets": -1}, {"crash_penalty_s": -1}, {"max_steps": 0}]
)
def test_bad_rules_are_refused(bad):
    with pytest.raises(ValueError):
        RaceRules(**bad)


def test_status_labels_match_deepracer():
    assert Status.TIME_UP.label == "Time Up"
    assert Status.LAP_COMPLETE.label == "Lap complete"
    assert {s.value for s in Status} >= {
        "prepare",
        "in_progress",
        "off_track",
        "crashed",
        "lap_complete",
        "reversed",
        "immobilized",
        "time_up",
    }


def test_a_lap_that_takes_too_long_is_time_up():
    t = tracker(lap_time_limit_s=2.0)
    out = drive(t, 0.01, 100)
    assert out.status is Status.TIME_UP and out.truncated and t.steps == 30
    default = RaceTracker(RaceRules(), 1000.0)  # 1 km: the limit grows with the track
    assert default._lap_limit == 2500.0
    assert RaceTracker(RaceRules(), LENGTH)._lap_limit == 180.0


def test_a_car_that_gains_no_ground_is_immobilized():
    t = tracker(stall_s=2.0)
    drive(t, 0.1, 10)
    # Circling: forward and back, never past its best, never 15 falling steps in a row.
    out = None
    for i in range(60):
        out = drive(t, 0.05 if (i // 5) % 2 == 0 else -0.05, 1)
        if out.done:
            break
    assert out.status is Status.IMMOBILIZED and 30 <= i + 1 <= 35  # 2 s after its best
    assert tracker(stall_s=None)._stalled() is False


def test_bots_pause_after_hitting_the_car_in_evaluation_only_by_default():
    assert RaceRules().bot_pause() == 0.0  # SimApp's training default
    assert RaceRules(resets=3).bot_pause() == 2.0  # its evaluation default
    assert RaceRules(bot_pause_s=1.5).bot_pause() == 1.5
    with pytest.raises(ValueError, match="bot_pause_s cannot be negative"):
        RaceRules(bot_pause_s=-1.0)
