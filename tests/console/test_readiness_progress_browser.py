"""The model page's readiness check moves by itself (Chromium through Playwright against
daphne on the test database): while the check runs, its "n of m conditions driven" line and
badge follow the worker's progress without a reload, and when it ends the page shows the
result. No worker: the test writes the check's progress as the worker would."""

from __future__ import annotations

import pytest
from django.contrib.auth import get_user_model
from django.test import Client

from tests.console.conftest import make_model
from training.models import JobStatus, RacingModel, ReadinessCheck

pytestmark = [pytest.mark.browser, pytest.mark.slow, pytest.mark.django_db(transaction=True),
              pytest.mark.timeout(300)]  # fmt: skip


def test_the_check_s_progress_moves_without_a_reload(browser, daphne):
    from playwright.sync_api import expect

    racer = get_user_model().objects.create_user("racer", password="pw-racer-123")
    model = make_model(racer, "car-one")
    RacingModel.objects.filter(pk=model.pk).update(has_checkpoint=True)
    check = ReadinessCheck.objects.create(
        model=model, track_id="racecraft_oval", status=JobStatus.QUEUED, cells_total=16,
    )  # fmt: skip
    client = Client()
    client.force_login(racer)
    context = browser.new_context(viewport={"width": 1280, "height": 900})
    context.add_cookies([{"name": "sessionid", "value": client.cookies["sessionid"].value,
                          "url": daphne.url}])  # fmt: skip
    context.set_default_timeout(30_000)
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(f"{daphne.url}/models/{model.pk}/")
    expect(page.locator("#readiness-status")).to_have_text("Queued")
    expect(page.locator("#readiness-live-note")).to_have_text(
        "This updates by itself every few seconds."
    )
    loaded = page.evaluate("performance.timeOrigin")

    ReadinessCheck.objects.filter(pk=check.pk).update(status=JobStatus.IN_PROGRESS, cells_done=4)
    expect(page.locator("#readiness-progress")).to_have_text("4 of 16 conditions driven")
    expect(page.locator("#readiness-status")).to_have_text("In progress")
    expect(page.locator("#readiness-status")).to_have_class("status status-busy")
    expect(page.locator("#readiness-bar")).to_have_attribute("style", "width: 25%;")
    assert page.evaluate("performance.timeOrigin") == loaded  # the same page, not a reload

    ReadinessCheck.objects.filter(pk=check.pk).update(
        status=JobStatus.COMPLETED, cells_done=16, verdict="Ready for the room", ready=True
    )
    expect(page.locator("#readiness-verdict")).to_have_text("Ready for the room")
    expect(page.locator("#readiness-status")).to_have_text("Completed")
    expect(page.locator("#readiness-live-note")).to_have_count(0)
    assert errors == []
