"""The league in a real browser (Chromium through Playwright) against daphne, the real ASGI
server, on the test database and Redis: an admin creates an event, two racers submit models,
their results appear in rank order and the leaderboard updates live without a reload; a
private race is reachable only through its invite link.

No training runs here: models are created READY with a checkpoint flag, and each submission's
evaluation is finished by writing its results (``finish_evaluation``), which fires the
league's signal and the live update exactly as the evaluator's completion does. The
evaluation itself is covered by tests/training.
"""

from __future__ import annotations

import threading
from pathlib import Path

import pytest
from django.contrib.auth import get_user_model
from django.db import connection
from django.test import Client
from league_helpers import finish_evaluation, lap, make_model, make_user

from leaderboard.models import Event, Submission
from tests.support import ChildProcess

ROOT = Path(__file__).resolve().parents[2]
ARTIFACTS = ROOT / "test-artifacts"

pytestmark = [
    pytest.mark.browser,
    pytest.mark.slow,
    pytest.mark.django_db(transaction=True),
]


def signed_in(browser, base_url: str, user):
    """A browser page whose session belongs to ``user`` (no login form involved)."""
    client = Client()
    client.force_login(user)
    context = browser.new_context(viewport={"width": 1360, "height": 900})
    context.add_cookies([{"name": "sessionid", "value": client.cookies["sessionid"].value,
                          "url": base_url}])  # fmt: skip
    page = context.new_page()
    page.set_default_timeout(15_000)
    return page


def shot(page, name: str) -> None:
    ARTIFACTS.mkdir(exist_ok=True)
    page.screenshot(path=str(ARTIFACTS / f"league-{name}.png"), full_page=True)


def submit(page, base_url: str, event: Event, model_name: str) -> Submission:
    page.goto(f"{base_url}/league/events/{event.pk}/")
    page.select_option("#submit select", label=model_name)
    page.click("#submit button[type=submit]")
    page.wait_for_selector("text=is submitted")
    return Submission.objects.get(model_name=model_name)


def finish_outside_the_browser_loop(job, laps) -> None:
    """Finish an evaluation from another thread, as a worker would: Playwright keeps an event
    loop in this one, where the channel layer's sync wrapper cannot run."""
    errors: list[BaseException] = []

    def work() -> None:
        try:
            finish_evaluation(job, laps)
        except BaseException as exc:  # noqa: BLE001 - re-raised in the test thread
            errors.append(exc)
        finally:
            connection.close()

    thread = threading.Thread(target=work)
    thread.start()
    thread.join(timeout=30)
    if errors:
        raise errors[0]


def ranked_aliases(page) -> list[str]:
    return page.eval_on_selector_all(
        "#leaderboard tbody tr", "rows => rows.map(r => r.dataset.racer)"
    )


def test_results_appear_live_in_rank_order_and_private_races_need_the_link(
    daphne: ChildProcess, browser
):
    server = daphne.url
    root = get_user_model().objects.create_superuser("root", "root@example.com", "pw-root-123")
    alice = make_user("alice", alias="Alice-R")
    bob = make_user("bob", alias="BobRacer")
    make_model(alice, "alice-arrow")
    make_model(bob, "bob-bolt")

    # An admin creates the event through the facilitator form.
    admin = signed_in(browser, server, root)
    admin.goto(f"{server}/league/events/new/")
    admin.fill("#id_name", "Grand Prix of the Oval")
    admin.fill("#id_description", "Fastest lap wins. Penalties count.")
    admin.select_option("#id_track_id", "racecraft_oval")
    admin.select_option("#id_ranking_method", "BEST_LAP")
    shot(admin, "event-form")
    admin.click("#event-form button[type=submit]")
    admin.wait_for_selector("h1:has-text('Grand Prix of the Oval')")
    event = Event.objects.get(name="Grand Prix of the Oval")
    assert not event.is_private and event.organiser == root

    # Both racers submit; Alice keeps the leaderboard open, the admin the wide screen.
    alice_page = signed_in(browser, server, alice)
    bob_page = signed_in(browser, server, bob)
    alice_sub = submit(alice_page, server, event, "alice-arrow")
    bob_sub = submit(bob_page, server, event, "bob-bolt")
    assert alice_page.inner_text(f'[data-my-submission="{alice_sub.pk}"] [data-status]') == (
        "Evaluating"
    )
    admin.goto(f"{server}/league/events/{event.pk}/screen/")
    for page in (alice_page, admin):
        page.wait_for_selector('[data-live-status][data-state="live"]')
        page.evaluate("window.__noReload = true")
    shot(alice_page, "event-pending")

    finish_outside_the_browser_loop(
        bob_sub.evaluation, [lap(10.5), lap(10.25, off_tracks=1), lap(11.0)]
    )
    alice_page.wait_for_selector('#leaderboard tr[data-racer="BobRacer"]')
    assert ranked_aliases(alice_page) == ["BobRacer"]

    finish_outside_the_browser_loop(
        alice_sub.evaluation, [lap(9.875), lap(9.9), lap(12.0, crashes=1)]
    )
    alice_page.wait_for_selector('#leaderboard tr[data-racer="Alice-R"].lb-new')
    assert ranked_aliases(alice_page) == ["Alice-R", "BobRacer"]
    times = alice_page.eval_on_selector_all("#leaderboard tbody td.time",
                                            "cells => cells.map(c => c.textContent)")  # fmt: skip
    gaps = alice_page.eval_on_selector_all("#leaderboard tbody td.gap",
                                           "cells => cells.map(c => c.textContent)")  # fmt: skip
    assert times == ["00:09.875", "00:10.250"] and gaps == ["—", "+0.375"]
    assert alice_page.inner_text(f'[data-my-submission="{alice_sub.pk}"] [data-status]') == (
        "Ranked"
    )
    shot(alice_page, "event-live")
    admin.wait_for_selector('#leaderboard tr[data-racer="Alice-R"]')
    assert ranked_aliases(admin) == ["Alice-R", "BobRacer"]
    shot(admin, "screen")
    for page in (alice_page, admin):
        assert page.evaluate("window.__noReload") is True  # updated in place

    # Alice organises a community race; Bob gets in only through its invite link.
    alice_page.goto(f"{server}/league/community/new/")
    alice_page.fill("#id_name", "Friday Night Oval")
    alice_page.select_option("#id_track_id", "racecraft_oval")
    alice_page.click("#event-form button[type=submit]")
    alice_page.wait_for_selector("#invite-url")
    invite = alice_page.input_value("#invite-url")
    race = Event.objects.get(name="Friday Night Oval")
    assert race.is_private and invite.endswith(f"/league/join/{race.invite_token}/")
    shot(alice_page, "community")

    response = bob_page.goto(f"{server}/league/events/{race.pk}/")
    assert response.status == 404
    bob_page.goto(f"{server}/league/")
    assert "Friday Night Oval" not in bob_page.content()
    bob_page.goto(invite)
    shot(bob_page, "join")
    bob_page.click("text=Join the race")
    bob_page.wait_for_selector("h1:has-text('Friday Night Oval')")
    assert bob_page.url.endswith(f"/league/events/{race.pk}/")
    bob_page.goto(f"{server}/league/")
    assert "Friday Night Oval" in bob_page.inner_text("#community")
    shot(bob_page, "home")
