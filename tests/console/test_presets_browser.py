"""The create page in Chromium: "Start from" the racing preset fills the action table,
hyperparameters and reward function, keeps the name typed before, and a model created from it
on two tracks ("Also train on") says so on its page, once a Celery worker has validated its
reward function on each track. daphne serves the console."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.support import ChildProcess

ARTIFACTS = Path(__file__).resolve().parents[2] / "test-artifacts" / "browser"
pytestmark = [pytest.mark.browser, pytest.mark.slow, pytest.mark.django_db(transaction=True),
              pytest.mark.timeout(600)]  # fmt: skip


@pytest.fixture
def page(browser, daphne: ChildProcess, celery_worker) -> Iterator[object]:
    context = browser.new_context(viewport={"width": 1360, "height": 900})
    context.set_default_timeout(30_000)
    page = context.new_page()
    page.base = daphne.url
    try:
        yield page
    finally:
        ARTIFACTS.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(ARTIFACTS / "presets-last.png"), full_page=True)


def test_start_from_the_racing_preset_on_two_tracks(page) -> None:
    from playwright.sync_api import expect

    page.goto(f"{page.base}/accounts/signup/")
    page.fill("#id_username", "speedy")
    page.fill("#id_password1", "a-long-pass-phrase-78")
    page.fill("#id_password2", "a-long-pass-phrase-78")
    page.click("button[type=submit]")
    expect(page.locator("h1")).to_have_text("Your models")

    page.goto(f"{page.base}/models/new/")
    expect(page.locator("input[name=start_from][value=deepracer_defaults]")).to_be_checked()
    expect(page.locator("tr.action-row")).to_have_count(10)
    expect(page.locator("input[name=action_speed]").first).to_have_value("0.5")
    page.fill("#id_name", "two-track-racer")
    page.check("input[name=start_from][value=racing]")
    page.click("#use-preset")

    expect(page.locator("input[name=start_from][value=racing]")).to_be_checked()
    expect(page.locator("#id_name")).to_have_value("two-track-racer")
    expect(page.locator("input[name=action_speed]")).to_have_count(6)
    expect(page.locator("input[name=action_speed]").first).to_have_value("3.5")  # the top speed
    expect(page.locator("input[name=action_speed]").last).to_have_value("2")
    expect(page.locator("#id_discount_factor")).to_have_value("0.98")
    expect(page.locator("#id_reward_function")).to_have_value(
        re.compile(r"speed made good along the track")
    )

    page.check("input[name=track_id][value=racecraft_oval]")
    page.locator("#multi-track summary").click()
    page.check("input[name=extra_track_ids][value=racecraft_summit]")
    page.fill("#id_max_minutes", "2")
    page.click("#create-submit")
    expect(page.locator("h1")).to_contain_text("two-track-racer", timeout=120_000)
    expect(page.locator("#config-extra-tracks")).to_contain_text("racecraft_summit (native)")
