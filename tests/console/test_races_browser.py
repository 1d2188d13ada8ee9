"""Racing a friend in a real browser (Chromium through Playwright) against daphne and a real
Celery worker on the test database, Redis and store: Bob opens his model to challenges on its
page; Alice starts a race against it from the Races page and watches it live at 1920x1080 on
the broadcast view (the video, the timing tower with both cars, the winner); the result is on
her races list and on the race's page with its replay; Bob sees that Alice raced his model.
Screenshots go to test-artifacts/races-*.png.

The worker starts once Alice's page is watching, so the race's frames are encoded from its
first step however fast the race runs. The cars are real checkpoints of an untrained network
whose every action drives straight (as in the race-day browser test)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from django.contrib.auth import get_user_model
from django.test import Client

from tests.support import celery_worker_process, constant
from training import services
from training.interchange.export import checkpoint_bytes
from training.models import JobStatus, RaceJob, RacingModel
from training.rl.checkpoints import new_model
from training.store import get_store, keys_for

REWARD = "def reward_function(p):\n    return 1.0\n"
ROOT = Path(__file__).resolve().parents[2]
ARTIFACTS = ROOT / "test-artifacts"
RACE_MS = 240_000
"""Longest wait for the race on the page, milliseconds (a lap of the oval, not paced)."""

pytestmark = [pytest.mark.browser, pytest.mark.slow, pytest.mark.django_db(transaction=True),
              pytest.mark.timeout(900)]  # fmt: skip


def car(username: str, speed: float) -> RacingModel:
    owner = get_user_model().objects.create_user(username, password="x-long-pass-1")
    model = services.model_create(owner=owner, name=f"{username}-car", track_id="racecraft_oval",
                                  action_space=constant(0, speed), validate_reward=False,
                                  reward_function=REWARD)  # fmt: skip
    torch.manual_seed(model.pk)
    get_store().put_bytes(keys_for(model.pk).best,
                          checkpoint_bytes(new_model(services.model_metadata(model))))  # fmt: skip
    services.model_mark_checkpoint(model=model)
    return model


def page_of(browser, base_url: str, user):
    context = browser.new_context(viewport={"width": 1920, "height": 1080})
    client = Client()
    client.force_login(user)
    context.add_cookies([{"name": "sessionid", "value": client.cookies["sessionid"].value,
                          "url": base_url}])  # fmt: skip
    page = context.new_page()
    page.set_default_timeout(30_000)
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    return page, errors


def shot(page, name: str) -> None:
    ARTIFACTS.mkdir(exist_ok=True)
    page.screenshot(path=str(ARTIFACTS / f"races-{name}.png"))


def test_a_racer_races_a_friends_open_model_and_watches_it(browser, daphne, child_env, tmp_path):
    alice_car, bob_car = car("alice", 4.0), car("bob", 3.5)
    base = daphne.url

    bob, bob_errors = page_of(browser, base, bob_car.owner)
    bob.goto(f"{base}/models/{bob_car.pk}/")
    bob.click("#open-challenges")
    bob.wait_for_selector("text=bob-car is open to challenges")
    bob.wait_for_selector("#close-challenges")

    alice, alice_errors = page_of(browser, base, alice_car.owner)
    alice.goto(f"{base}/races/")
    alice.click("#new-race")
    alice.select_option("#id_model", str(alice_car.pk))
    alice.check(f"input[name=opponents][value='{bob_car.pk}']")
    alice.select_option("#id_track_id", "racecraft_oval")
    alice.fill("#id_laps", "1")
    shot(alice, "new")
    alice.click("#start-race")
    race = RaceJob.objects.get()
    alice.wait_for_selector("[data-live-status][data-state=live]")
    assert alice.inner_text("[data-race-title]") == "alice-car v bob-car"
    assert RaceJob.objects.get(pk=race.pk).status == JobStatus.QUEUED

    with celery_worker_process(queues=["evaluation"], env=child_env,
                               log_path=tmp_path / "worker.log"):  # fmt: skip
        alice.wait_for_selector("[data-video][src^='blob:']", timeout=RACE_MS)
        for name in ("alice-car", "bob-car"):  # the race-day broadcast's tower and PiP names
            alice.wait_for_selector(f"[data-timing] tr[data-name='{name}']", timeout=RACE_MS)
            alice.wait_for_selector(f".tv-pip-label:text-is('{name}')")
        alice.wait_for_selector("[data-clock]:not(:text-is('0:00.0'))")
        assert alice.locator("[data-tower]").is_visible()
        assert alice.locator("#stop-race").is_visible()  # the challenger may stop it
        shot(alice, "live")
        alice.wait_for_selector("[data-winner]:not([hidden])", timeout=RACE_MS)
    race.refresh_from_db()
    assert race.status == JobStatus.COMPLETED, race.error
    winner = next(c for c in race.car_rows if c["model"] == race.results["winner"])
    assert alice.inner_text("[data-winner-name]") == winner["name"]
    alice.wait_for_selector("[data-race-status]:text-is('Finished')")
    assert alice.locator("#stop-race").count() == 0
    shot(alice, "winner")

    alice.click("[data-results-link]")
    alice.wait_for_selector(f"#race-results tr[data-car='{winner['name']}'][data-winner]")
    assert alice.locator("#race-replay video").count() == 1 and race.has_video
    assert alice.locator("#race-traces").count() == 1
    shot(alice, "result")
    alice.goto(f"{base}/races/")
    assert alice.inner_text(f"tr[data-race='{race.pk}'] [data-winner]") == winner["name"]

    bob.goto(f"{base}/races/")
    row = bob.locator("#raced-against-me tr[data-challenger='alice']")
    assert "bob-car" in row.inner_text()
    shot(bob, "raced-by")
    assert alice_errors == [] and bob_errors == []
