"""A race day in a real browser (Chromium through Playwright) against daphne and a real Celery
worker on the test database, Redis and store: Fran the facilitator queues a racer's solo run,
seeds the bracket (its match joins the queue) and launches both races; the broadcast page at
1920x1080, opened logged out through the spectator link, shows the live video, the race
clock, sector colours and the winner overlay; Alice, a racer, is refused the controls.
Screenshots go to test-artifacts/.

The cars are real checkpoints of an untrained network whose every action drives straight at
4 m/s (3.5 m/s): without penalties such a car laps the oval in about 9 s of race clock, which
the race day runs at real time (at 2 m/s with 1 s penalties, 24 s a race).
"""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from django.test import Client
from league_helpers import make_event, make_user

from leaderboard.models import BracketMatch, RaceDaySlot, Submission
from tests.support import constant
from training import services
from training.interchange.export import checkpoint_bytes
from training.rl.checkpoints import new_model
from training.store import get_store, keys_for

ROOT = Path(__file__).resolve().parents[2]
ARTIFACTS = ROOT / "test-artifacts"
RACE_S = 120_000
"""Longest wait for a race on the broadcast page, milliseconds (it runs ~10 s at real time)."""

pytestmark = [pytest.mark.browser, pytest.mark.slow, pytest.mark.django_db(transaction=True)]


def entry(event, name: str, speed: float) -> Submission:
    """A racer's entry with its weights kept as a league entry is."""
    racer = make_user(name, alias=name.title())
    model = services.model_create(
        owner=racer,
        name=f"{name}-car",
        track_id="racecraft_oval",
        action_space=constant(0, speed),
        validate_reward=False,
        reward_function="def reward_function(p):\n    return 1.0\n",
    )
    torch.manual_seed(model.pk)
    get_store().put_bytes(keys_for(model.pk).best,
                          checkpoint_bytes(new_model(services.model_metadata(model))))  # fmt: skip
    services.model_mark_checkpoint(model=model)
    sub = Submission.objects.create(
        event=event, racer=racer, model=model, model_name=model.name,
        status=Submission.Status.RANKED, entered_model_id=model.pk,
        model_metadata=services.model_metadata(model).to_json(),
    )  # fmt: skip
    sub.frozen_checkpoint = services.model_freeze(model=model, scope=f"event-{event.pk}",
                                                  entry=sub.pk)  # fmt: skip
    sub.save()
    return sub


def page_of(browser, base_url: str, user=None, *, width: int = 1360, height: int = 900):
    context = browser.new_context(viewport={"width": width, "height": height})
    if user is not None:
        client = Client()
        client.force_login(user)
        context.add_cookies([{"name": "sessionid", "value": client.cookies["sessionid"].value,
                              "url": base_url}])  # fmt: skip
    page = context.new_page()
    page.set_default_timeout(30_000)
    return page


def shot(page, name: str) -> None:
    ARTIFACTS.mkdir(exist_ok=True)
    page.screenshot(path=str(ARTIFACTS / f"raceday-{name}.png"))


def test_a_facilitator_runs_a_race_day_on_the_broadcast_page(browser, daphne, celery_worker):
    fran = make_user("fran", alias="Fran", facilitator=True)
    alice = make_user("alice", alias="Alice")
    event = make_event(fran, name="Summit race day", min_laps=1, max_laps=1,
                       off_track_penalty_s=0.0, collision_penalty_s=0.0, bracket_size=4,
                       bracket_laps=1, bracket_on_race_day=True)  # fmt: skip
    ada, bo = entry(event, "ada", 4.0), entry(event, "bo", 3.5)
    Submission.objects.filter(pk=ada.pk).update(ranked=True, score_ms=30_000)
    Submission.objects.filter(pk=bo.pk).update(ranked=True, score_ms=31_000)
    base = daphne.url

    control = page_of(browser, base, fran)
    control.goto(f"{base}/league/events/{event.pk}/race-day/")
    control.select_option("[data-testid=entry]", str(ada.pk))
    control.click("text=Add to the queue")
    control.wait_for_selector("text=ada-car joined the queue")
    control.goto(f"{base}/league/events/{event.pk}/bracket/")
    control.click("[data-testid=seed-bracket]")  # the final, ada v bo, joins the queue
    control.wait_for_selector("[data-match='1-0']")
    control.goto(f"{base}/league/events/{event.pk}/race-day/")
    control.click("text=Make a spectator link")
    spectator_url = control.input_value("#spectator-url")
    assert "watch=" in spectator_url

    screen = page_of(browser, base, width=1920, height=1080)  # logged out: the link alone
    screen.goto(spectator_url)
    screen.wait_for_selector("[data-live-status][data-state=live]")
    shot(screen, "broadcast-waiting")

    turns = [(f"{event.name}: ada-car", ["ada-car"]),
             (f"{event.name}: round 1, match 1", ["ada-car", "bo-car"])]  # fmt: skip
    for turn, (title, cars) in enumerate(turns, start=1):
        control.click("[data-testid=launch-next]")
        control.wait_for_selector(f"text=On track: {title}")
        # This race's own pictures and timing, not the last race's still on the screen.
        screen.wait_for_selector(f"[data-race-title]:text-is('{title}')", timeout=RACE_S)
        screen.wait_for_selector("[data-winner]", state="hidden")
        for car in cars:
            screen.wait_for_selector(f"[data-timing] tr:has-text('{car}')", timeout=RACE_S)
        screen.wait_for_selector("[data-video][src^='blob:']")
        screen.wait_for_selector("[data-clock]:not(:text-is('0:00.0'))")
        screen.wait_for_selector("[data-timing] .bc-s.purple", timeout=RACE_S)
        shot(screen, f"broadcast-race-{turn}")
        screen.wait_for_selector("[data-winner]:not([hidden])", timeout=RACE_S)
        # The winner shows from the race's last frame (its timing); the job's results land
        # just after it.
        for _ in range(RACE_S // 100):
            slot = RaceDaySlot.objects.select_related("race").get(race__title=title)
            if slot.status != RaceDaySlot.Status.RUNNING:
                break
            screen.wait_for_timeout(100)
        assert slot.status == RaceDaySlot.Status.DONE
        results = slot.race.results
        winner = next(c for c in results["cars"] if c["model"] == results["winner"])
        assert screen.inner_text("[data-winner-name]") == winner["name"]
        assert screen.inner_text("[data-winner-time]") != ""  # from the spectators' payload
        assert slot.race.has_video and winner["finished"]
        shot(screen, f"broadcast-winner-{turn}")
        control.reload()
    event.refresh_from_db()
    assert event.bracket and BracketMatch.objects.get(event=event).winner_id is not None

    racer = page_of(browser, base, alice)
    response = racer.goto(f"{base}/league/events/{event.pk}/race-day/")
    assert response.status == 403
    assert racer.locator("[data-testid=launch-next]").count() == 0
    shot(racer, "refused")
