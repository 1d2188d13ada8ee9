"""Evaluation runs: laps back to back with resets and penalties, DeepRacer's metrics, a
playable MP4, live frames, and stopping. A scripted driver stands in for a trained policy."""

from __future__ import annotations

import pytest

from racing.controllers import PurePursuitDriver
from training.rl.evaluation import EvaluationError, EvaluationSettings, evaluate
from training.rollout.envs import EnvSpec

CONTINUOUS = {"steering_angle": {"low": -30, "high": 30}, "speed": {"low": 0.5, "high": 4}}
SPEC = EnvSpec(track="racecraft_oval", action_space=CONTINUOUS)


@pytest.fixture
def driven(monkeypatch):
    """Run evaluate() with the pure-pursuit driver on the env it creates."""
    import training.rl.evaluation as evaluation

    made = {}
    original = evaluation.evaluation_env

    def capture(spec, settings):
        env = original(spec, settings)
        made["env"] = env
        made["driver"] = PurePursuitDriver(env.track)
        return env

    monkeypatch.setattr(evaluation, "evaluation_env", capture)

    def policy(obs):
        env = made["env"]
        return env.actions.encode(*made["driver"].act(env.pose))

    return policy


def test_three_clean_laps_with_metrics_video_and_frames(driven):
    frames = []
    progress = []
    report = evaluate(driven, SPEC, EvaluationSettings(laps=3), on_progress=progress.append,
                      on_frame=frames.append, frames_wanted=lambda: True)  # fmt: skip
    assert report.completed_laps == 3
    assert [lap.trial for lap in report.laps] == [1, 2, 3]
    assert all(lap.status == "lap_complete" and lap.resets == 0 for lap in report.laps)
    assert all(5.0 < lap.time_s < 15.0 for lap in report.laps)
    entry = report.metrics_json()["metrics"][0]
    assert {"trial", "completion_percentage", "elapsed_time_in_milliseconds", "episode_status",
            "off_track_count", "crash_count", "reset_count"} <= set(entry)  # fmt: skip
    assert entry["episode_status"] == "Lap complete" and entry["completion_percentage"] == 100
    assert report.video_mp4[4:8] == b"ftyp" and len(report.video_mp4) > 10_000
    assert len(report.rows) == report.steps and len(report.rows[0]) == 19
    assert progress[-1]["laps_done"] == 3
    assert frames and frames[0]["camera"][:2].tobytes() == b"\xff\xd8"  # JPEG


def test_penalties_count_in_lap_time(driven, monkeypatch):
    """A car that leaves the track is reset with the penalty, and the lap time includes it."""
    calls = {"n": 0}

    def swerving(obs):
        calls["n"] += 1
        if 30 <= calls["n"] < 60:  # full lock for two seconds: off the track
            import numpy as np

            return np.array([30.0, 3.0], dtype=np.float32)
        return driven(obs)

    report = evaluate(swerving, SPEC, EvaluationSettings(laps=3, off_track_penalty_s=4.0,
                                                         record_video=False))  # fmt: skip
    first = report.laps[0]
    assert first.off_tracks >= 1 and first.resets == first.off_tracks
    assert first.off_track_penalty_s == 4.0 * first.off_tracks
    assert first.time_s > report.laps[1].time_s + 3.0  # the penalty is in the time
    assert report.completed_laps == 3


def test_stopping_keeps_what_was_measured(driven):
    report = evaluate(driven, SPEC, EvaluationSettings(laps=3, record_video=False),
                      should_stop=lambda: True)  # fmt: skip
    assert report.stopped and report.steps == 1 and report.completed_laps == 0


@pytest.mark.parametrize(
    "bad",
    [
        {"laps": 2},
        {"laps": 6},
        {"off_track_penalty_s": -1},
        {"crash_penalty_s": 61},
        {"resets": -1},
    ],
)
def test_settings_outside_deepracer_ranges(bad):
    with pytest.raises(EvaluationError):
        EvaluationSettings(**bad)
