"""Saving a reward function in Chromium (issue 10): the page says it is validating, the
worker validates, and the page saves by itself once it passes - or marks the error's line.
daphne and a real Celery worker on the interactive queue; the editor is CodeMirror when its
bundle is built, else the plain text box."""

from __future__ import annotations

import re

import pytest
from django.contrib.auth import get_user_model

from tests.conftest import PASSWORD
from tests.console.conftest import make_model
from training.models import RacingModel

pytestmark = [pytest.mark.browser, pytest.mark.slow, pytest.mark.django_db(transaction=True),
              pytest.mark.timeout(600)]  # fmt: skip
NEW = "def reward_function(params):\n    return 0.75\n"
BROKEN = "def reward_function(params):\n    x = 1\n    return params['nope']\n"
WORKER_S = 180_000
"""How long the page may wait for the worker's answer (ms; a loaded machine is slow)."""


def write_reward(page, source: str) -> None:
    if page.locator("#reward-editor .cm-content").count():
        page.click("#reward-editor .cm-content")
        page.keyboard.press("Control+a")
        page.keyboard.press("Delete")
        page.keyboard.insert_text(source)
    else:
        page.fill("#id_reward_function", source)


def test_a_reward_edit_validates_on_the_worker_then_saves(browser, daphne, celery_worker,
                                                          store_dir):  # fmt: skip
    from playwright.sync_api import expect

    alice = get_user_model().objects.create_user("alice", password=PASSWORD)
    model = make_model(alice)
    page = browser.new_context().new_page()
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(f"{daphne.url}/accounts/login/")
    page.fill("#id_username", "alice")
    page.fill("#id_password", PASSWORD)
    page.click("button[type=submit]")
    expect(page).to_have_url(re.compile(r"/models/$"))

    page.goto(f"{daphne.url}/models/{model.pk}/reward/")
    write_reward(page, BROKEN)
    page.click("#reward-save")
    # The page comes back at once and says it is validating; the worker answers with the line.
    error = page.locator("#reward-result .error-list li").first
    expect(error).to_contain_text("Line 3", timeout=WORKER_S)
    expect(error).to_contain_text("nope")
    model.refresh_from_db()
    assert model.reward_function != BROKEN  # nothing saved

    write_reward(page, NEW)
    page.click("#reward-save")
    expect(page.locator("#pending-validation")).to_be_visible()
    # Once it passes the page posts the form again by itself and lands on the model.
    expect(page.locator(".flash")).to_contain_text("Reward function saved", timeout=WORKER_S)
    expect(page).to_have_url(re.compile(rf"/models/{model.pk}/$"))
    assert RacingModel.objects.get(pk=model.pk).reward_function.replace("\r\n", "\n") == NEW
    assert not errors, errors
