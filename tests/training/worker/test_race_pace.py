"""A racer's race from the Races page runs at real time while they watch it, at full speed
otherwise (training/worker/race.py: WatchedPace); a race day's races keep their own pacing.
A fake clock: nothing here depends on the machine's speed."""

from __future__ import annotations

import pytest

from training.models import RaceJob
from training.services.challenges import CHALLENGE
from training.worker.race import WatchedPace, watched_at_real_time
from training.worker.racelive import FRAME_S


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0
        self.slept: list[float] = []

    def __call__(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.slept.append(seconds)
        self.now += seconds


def test_frames_wait_for_real_time_only_while_someone_watches() -> None:
    clock, watching, sent = FakeClock(), [False], []
    pace = WatchedPace(lambda: watching[0], lambda rgb, header: sent.append(header["n"]),
                       check_s=1.0, clock=clock, sleep=clock.sleep)  # fmt: skip
    for n in range(30):  # nobody watches: no waiting at all (the simulation's own speed)
        pace.frame(None, {"n": n})
        clock.now += 0.01
    assert clock.slept == [] and sent == list(range(30))
    watching[0] = True
    clock.now += 1.0  # the next check sees the viewer
    for n in range(30, 45):  # 15 frames of race clock: about 1 s of wall time
        pace.frame(None, {"n": n})
        clock.now += 0.01  # the step itself takes 10 ms
    assert len(clock.slept) == 14 and all(s == pytest.approx(FRAME_S - 0.01) for s in clock.slept)
    assert pace.waited_s == pytest.approx(14 * (FRAME_S - 0.01))
    clock.now += 5.0  # a slow step: behind, the next frames do not rush to catch up
    pace.frame(None, {"n": 45})
    assert len(clock.slept) == 14
    pace.frame(None, {"n": 46})
    assert clock.slept[-1] == pytest.approx(FRAME_S)
    assert sent == list(range(47))  # every frame handed on, in order


@pytest.mark.parametrize(("purpose", "paced", "expected"),
                         [(CHALLENGE, False, True), (CHALLENGE, True, False),
                          ("", False, False), ("race_day", True, False)])  # fmt: skip
def test_which_races_run_at_real_time_while_watched(purpose, paced, expected) -> None:
    assert watched_at_real_time(RaceJob(purpose=purpose, paced=paced)) is expected


def test_pacing_changes_nothing_in_the_race() -> None:
    """Results (and the MP4's frames, drawn before on_frame) are the same paced or not."""
    from racing.headtohead import Racer
    from racing.tracks import TrackCatalog
    from training.rl.race import RaceEntry, RaceSettings, run_race

    oval = TrackCatalog([]).load("racecraft_oval").in_direction("native")
    space = [{"steering_angle": 0, "speed": 1.0}, {"steering_angle": 10, "speed": 0.8}]

    def race(on_frame) -> dict:
        entries = [RaceEntry(key=k, name=f"car{k}", racer=Racer(action_space=space),
                             policy=lambda obs, k=k: k % 2) for k in (1, 2)]  # fmt: skip
        steps = iter(range(30))
        return run_race(entries, oval, RaceSettings(laps=1, time_limit_s=12.0, record_video=False),
                        on_frame=on_frame, should_stop=lambda: next(steps, None) is None
                        ).to_json()  # fmt: skip

    clock, headers = FakeClock(), []
    pace = WatchedPace(lambda: True, lambda rgb, header: headers.append(header["timing"]),
                       clock=clock, sleep=clock.sleep)  # fmt: skip
    assert race(pace.frame) == race(lambda rgb, header: None)
    assert pace.waited_s > 0 and len(headers) == 31  # a frame a step, the stopping one too
