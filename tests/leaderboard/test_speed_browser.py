"""Live speed control in a real browser (Chromium through Playwright) against daphne and a
real Celery worker on the test database, Redis and store: Fran launches Ada's race-day turn;
Ada, on her phone (375 px wide), opens the speed page from her "up next" notice and taps 1.5×
while her car is on track; the car drives faster from then on and its sim-trace records the
multiplier of every step. Bo, who is not on track, is refused the page. Screenshots go to
test-artifacts/.

Ada's car is an untrained network whose one action drives straight at 1 m/s; the turn runs at
real time, so there is time to change the speed during it.
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from league_helpers import make_event, make_user
from test_race_day_browser import entry, page_of

from leaderboard.models import Notification
from training.interchange.layout import RaceKeys
from training.models import JobStatus, RaceJob
from training.services.race_control import race_speed_applied
from training.store import get_store

ROOT = Path(__file__).resolve().parents[2]
ARTIFACTS = ROOT / "test-artifacts"
pytestmark = [pytest.mark.browser, pytest.mark.slow, pytest.mark.django_db(transaction=True)]


def wait_for_status(race_id: int, statuses: tuple[str, ...], within_s: float = 180.0) -> RaceJob:
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline:
        race = RaceJob.objects.get(pk=race_id)
        if race.status in statuses:
            return race
        time.sleep(0.25)
    pytest.fail(f"race {race_id} did not reach {statuses} in {within_s:.0f} s")


def shot(page, name: str) -> None:
    ARTIFACTS.mkdir(exist_ok=True)
    page.screenshot(path=str(ARTIFACTS / f"speed-{name}.png"), full_page=True)


def test_a_racer_changes_speed_during_a_race_day_turn(browser, daphne, celery_worker):
    fran = make_user("fran", alias="Fran", facilitator=True)
    event = make_event(fran, name="Live speed day", min_laps=1, max_laps=1,
                       off_track_penalty_s=0.0, collision_penalty_s=0.0,
                       live_speed_control=True)  # fmt: skip
    ada, bo = entry(event, "ada", 1.0), entry(event, "bo", 1.0)
    base = daphne.url
    control = page_of(browser, base, fran)
    control.goto(f"{base}/league/events/{event.pk}/race-day/")
    assert "Live speed control is on" in control.inner_text("[data-testid=speed-note]")
    for sub in (ada, bo):
        control.select_option("[data-testid=entry]", str(sub.pk))
        control.click("text=Add to the queue")
        control.wait_for_selector(f"text={sub.model_name} joined the queue")

    phone = page_of(browser, base, ada.racer, width=375, height=740)
    link = Notification.objects.get(user=ada.racer, message__contains="up next").link
    assert link == f"/league/events/{event.pk}/speed/"
    refused = phone.goto(f"{base}{link}")  # up next, not on track yet
    assert refused.status == 403
    assert "only during your turn" in phone.inner_text("[data-testid=speed-error]")

    control.click("[data-testid=launch-next]")
    control.wait_for_selector("text=On track:")
    race = RaceJob.objects.get(race_day_slots__event=event)
    # The race reports what the car drives at once it drives: until then the page says so.
    deadline = time.monotonic() + 180
    while race_speed_applied(race.pk, 0) is None:
        assert time.monotonic() < deadline, "the car never started"
        time.sleep(0.25)
    phone.goto(f"{base}{link}")
    assert phone.inner_text("[data-testid=speed-value]") == "1.00"
    assert phone.get_attribute("[data-testid=speed-driving]", "data-driving") == "1.00"
    width = phone.evaluate("document.documentElement.scrollWidth")
    assert width <= 375  # nothing wider than the phone
    box = phone.locator("[data-testid=speed-up]").bounding_box()
    assert box["height"] >= 48 and box["width"] >= 120  # a thumb's target
    shot(phone, "phone-before")
    phone.click("[data-testid='speed-1.5']")
    phone.wait_for_selector("[data-testid=speed-value]:text-is('1.50')")
    phone.click("[data-testid=speed-down]")  # 1.4, then back up: the buttons follow the value
    phone.wait_for_selector("[data-testid=speed-value]:text-is('1.40')")
    phone.click("[data-testid=speed-up]")
    phone.wait_for_selector("[data-testid=speed-value]:text-is('1.50')")
    assert phone.locator("[data-testid=speed-error]").is_hidden()
    shot(phone, "phone-after")

    other = page_of(browser, base, bo.racer, width=375, height=740)
    answer = other.goto(f"{base}{link}")
    assert answer.status == 403 and "not your turn" in other.inner_text("[data-testid=speed-error]")

    race = wait_for_status(race.pk, (JobStatus.COMPLETED, JobStatus.FAILED, JobStatus.CANCELED))
    assert race.status == JobStatus.COMPLETED, race.error
    store, keys = get_store(), RaceKeys(race.pk)
    model_id = race.entries[0]["model"]
    (trace_key,) = [k for k in store.list(keys.car_folder(model_id)) if k.endswith(".csv")]
    lines = store.get_bytes(trace_key).decode().strip().split("\n")
    assert lines[0].endswith(",speed_multiplier")
    speeds = [line.rsplit(",", 1)[1] for line in lines[1:]]
    # The worker reads the value a few times a second, so it may have caught the 1.40 between
    # the two clicks: the first change is either value, never anything else.
    changed = next(i for i, speed in enumerate(speeds) if speed != "1.00")
    assert changed >= 1 and set(speeds[:changed]) == {"1.00"}  # it drove at 1.0 first
    assert speeds[-1] == "1.50" and set(speeds[changed:]) <= {"1.40", "1.50"}
