"""The analysis page in Chromium: a model trained by a real Celery worker, its heatmap switched
between reward, speed and action, an episode picked from the table and replayed with an
edited reward (the replay runs as a Celery task, in the sandbox)."""

from __future__ import annotations

import re
import time

import pytest
from django.contrib.auth import get_user_model

from tests.console.test_console_browser import ARTIFACTS, page, web  # noqa: F401 - fixtures
from training import services
from training.models import JobStatus, TrainingJob

pytestmark = [pytest.mark.browser, pytest.mark.slow, pytest.mark.django_db(transaction=True),
              pytest.mark.timeout(900)]  # fmt: skip
PASSWORD = "a-long-pass-phrase-77"
REWARD = "def reward_function(params):\n    return 1.0 - params['distance_from_center']\n"
EDITED = "def reward_function(params):\n    return 10.0 * params['speed']\n"


def _wait(predicate, timeout: float, what: str):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.5)
    pytest.fail(f"timed out waiting for {what}")


@pytest.fixture
def trained(celery_worker) -> int:
    """Id of a model trained for one logged iteration by the Celery worker (set up before the
    browser: Playwright's event loop forbids the ORM in the test's thread)."""
    user = get_user_model().objects.create_user("analyst", password=PASSWORD)
    model = services.model_create(
        owner=user, name="analysed", track_id="racecraft_oval", reward_function=REWARD,
        action_space=[{"steering_angle": a, "speed": 1.5} for a in (-30, 0, 30)],
        hyperparameters={"num_episodes_between_training": 4, "num_epochs": 3,
                         "batch_size": 32},
        max_minutes=5, seed=2,
    )  # fmt: skip
    job = services.training_start(model=model, user=user)
    _wait(lambda: TrainingJob.objects.get(pk=job.pk).episodes >= 4, 400, "a logged iteration")
    services.job_stop(job=TrainingJob.objects.get(pk=job.pk), user=user)
    _wait(lambda: TrainingJob.objects.filter(pk=job.pk, status=JobStatus.COMPLETED).exists(),
          200, "the stopped job")  # fmt: skip
    return model.pk


def test_analysis_heatmaps_episode_and_replay(trained, page, web) -> None:  # noqa: F811
    from playwright.sync_api import expect

    page.goto(f"{web}/accounts/login/")
    page.fill("#id_username", "analyst")
    page.fill("#id_password", PASSWORD)
    page.click("button[type=submit]")
    page.wait_for_url(lambda url: "/accounts/login/" not in url)
    page.goto(f"{web}/models/{trained}/")
    page.click("#analysis-link")
    page.wait_for_url(f"**/models/{trained}/analysis/")
    canvas = page.locator("#track-canvas")
    for kind in ("reward", "speed", "action"):
        page.select_option("#heatmap-kind", kind)
        expect(canvas).to_have_attribute("data-kind", kind)
        assert kind in page.locator("#track-legend").inner_text().lower() or kind == "action"
    assert "Most chosen action" in page.locator("#track-legend").inner_text()
    page.locator("#episode-table tbody tr").first.click()
    expect(canvas).to_have_attribute("data-episode", re.compile(r"^0/\d+$"))
    page.fill("#replay-source", EDITED)
    page.click("#replay-run")
    totals = page.locator("#replay-totals")
    expect(totals).to_have_attribute("data-new-total", re.compile(r"\d"), timeout=120_000)
    assert float(totals.get_attribute("data-new-total")) > 0
    assert "recorded" in totals.inner_text()
    page.screenshot(path=str(ARTIFACTS / "analysis.png"), full_page=True)
    assert not page.errors, page.errors
