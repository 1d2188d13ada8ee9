"""The readiness check in Chromium (issue 51): started from the model page, run by a real
worker on the ``readiness`` queue, its table, verdict and a worst-case video on the page; then
two models side by side on the compare page. daphne serves the console on the test database."""

from __future__ import annotations

import pytest
from django.contrib.auth import get_user_model

from tests.support import celery_worker_process
from training import services
from training.models import JobStatus, RacingModel, ReadinessCheck

PASSWORD = "pw-racer-123"
ACTIONS = [{"steering_angle": a, "speed": 1.0} for a in (-30, 0, 30)]

pytestmark = [pytest.mark.browser, pytest.mark.slow, pytest.mark.django_db(transaction=True),
              pytest.mark.timeout(600)]  # fmt: skip


def trained_model(owner, name: str) -> RacingModel:
    """A model with an (untrained) network stored as its best checkpoint."""
    import torch

    from training.interchange.export import checkpoint_bytes
    from training.rl.checkpoints import new_model
    from training.store import get_store, keys_for

    model = services.model_create(
        owner=owner, name=name, track_id="racecraft_oval", action_space=ACTIONS,
        reward_function="def reward_function(params):\n    return 1.0\n",
        validate_reward=False,
    )  # fmt: skip
    torch.manual_seed(7)
    weights = checkpoint_bytes(new_model(services.model_metadata(model)))
    get_store().put_bytes(keys_for(model.pk).best, weights)
    services.model_mark_checkpoint(model=model)
    return model


@pytest.fixture
def readiness_worker(child_env, tmp_path):
    with celery_worker_process(
        queues=["readiness"], env=child_env, log_path=tmp_path / "worker.log"
    ) as worker:
        yield worker


def test_a_check_from_the_model_page_shows_its_table_and_a_worst_case_video(
    browser, daphne, readiness_worker
):
    from playwright.sync_api import expect

    racer = get_user_model().objects.create_user("racer", password=PASSWORD)
    model = trained_model(racer, "car-one")
    context = browser.new_context(viewport={"width": 1280, "height": 900})
    context.set_default_timeout(30_000)
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(f"{daphne.url}/accounts/login/")
    page.fill("#id_username", "racer")
    page.fill("#id_password", PASSWORD)
    page.click("button[type=submit]")
    expect(page).not_to_have_url(f"{daphne.url}/accounts/login/")

    page.goto(f"{daphne.url}/models/{model.pk}/")
    expect(page.locator("#readiness-none")).to_contain_text("No readiness check yet")
    page.click("#start-readiness")
    expect(page.locator("#readiness-status")).to_be_visible()
    check = ReadinessCheck.objects.get(model=model)
    for _ in range(480):  # the worker drives 16 cells; the page shows the end on a reload
        check.refresh_from_db()
        if not check.is_active:
            break
        page.wait_for_timeout(500)
    assert check.status == JobStatus.COMPLETED, check.error
    page.reload()
    expect(page.locator("#readiness-status")).to_have_text("Completed")
    table = page.locator("#readiness-table")
    expect(table).to_be_visible()
    expect(table.locator("thead th")).to_have_count(4)  # conditions + three strengths
    expect(table.locator("tbody tr")).to_have_count(6)  # the clean world + five families
    expect(page.locator("#readiness-verdict")).to_contain_text("Not ready")
    video = page.locator("video.readiness-video").first
    expect(video).to_be_visible()
    src = video.get_attribute("src")
    assert src == f"/readiness/{check.pk}/video/{check.videos[0]}.mp4"
    response = page.request.get(f"{daphne.url}{src}")
    assert response.status == 200 and response.body()[4:8] == b"ftyp"

    # Side by side with another of the racer's models that has a finished check.
    other = trained_model(racer, "car-two")
    ReadinessCheck.objects.create(
        model=other, track_id="racecraft_oval", status=JobStatus.COMPLETED,
        verdict="Ready: completes at least 100 % of laps under every family at medium strength",
        plan=check.plan, results={"cells": [
            {"family": "clean", "strength": 0.0, "laps_completed": 2, "laps_attempted": 2,
             "completion_pct": 100.0, "median_lap_s": 8.0}]},
    )  # fmt: skip
    page.goto(f"{daphne.url}/readiness/compare/?a={model.pk}&b={other.pk}")
    compare = page.locator("#compare-table")
    expect(compare.locator("thead")).to_contain_text("car-one")
    expect(compare.locator("thead")).to_contain_text("car-two")
    expect(compare).to_contain_text("Ready: completes at least 100 %")
    assert errors == []
    context.close()
