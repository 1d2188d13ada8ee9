"""The whole console in Chromium: sign up, create a model (a broken reward function first),
train it with a real Celery worker while watching video and the chart, stop, evaluate,
download the car model, clone and delete. The web server is daphne (HTTP + websockets) in a
subprocess on the test database; screenshots go to test-artifacts/browser/."""

from __future__ import annotations

import io
import re
import tarfile
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.support import ChildProcess

ROOT = Path(__file__).resolve().parents[2]
ARTIFACTS = ROOT / "test-artifacts" / "browser"
BROKEN = "def reward_function(params):\n    speed = params['speed']\n    return speed +\n"
FIXED = (
    "def reward_function(params):\n"
    "    if not params['all_wheels_on_track']:\n"
    "        return 1e-3\n"
    "    return 1.0 - params['distance_from_center'] / params['track_width']\n"
)

pytestmark = [pytest.mark.browser, pytest.mark.slow, pytest.mark.django_db(transaction=True),
              pytest.mark.timeout(900)]  # fmt: skip


@pytest.fixture
def web(daphne: ChildProcess) -> Iterator[str]:
    """The console's base URL, with the CodeMirror bundle built; daphne's log is kept."""
    from django.core.management import call_command

    call_command("build_assets")  # the CodeMirror bundle (npm ci + esbuild when missing)
    try:
        yield daphne.url
    finally:
        ARTIFACTS.mkdir(parents=True, exist_ok=True)
        (ARTIFACTS / "daphne.log").write_text(daphne.log())


@pytest.fixture
def page(browser, web):
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    context = browser.new_context(viewport={"width": 1360, "height": 900}, accept_downloads=True)
    context.set_default_timeout(30_000)
    page = context.new_page()
    page.errors = []
    page.on("pageerror", lambda e: page.errors.append(str(e)))
    try:
        yield page
    finally:
        page.screenshot(path=str(ARTIFACTS / "last.png"), full_page=True)


def shot(page, name: str, selector: str | None = None) -> None:
    # The sticky top bar would cover the top of an element screenshot.
    page.add_style_tag(content=".topbar { position: static !important; }")
    target = page.locator(selector) if selector else page
    target.screenshot(path=str(ARTIFACTS / f"{name}.png"))


def set_editor(page, source: str) -> None:
    page.click("#reward-editor .cm-content")
    page.keyboard.press("Control+a")
    page.keyboard.press("Delete")
    page.keyboard.insert_text(source)


def test_sign_up_create_train_watch_stop_evaluate_download_clone_delete(page, web, celery_worker):
    from playwright.sync_api import expect

    log = celery_worker.log_path
    page.goto(f"{web}/accounts/signup/")
    page.fill("#id_username", "racer")
    page.fill("#id_password1", "a-long-pass-phrase-77")
    page.fill("#id_password2", "a-long-pass-phrase-77")
    page.click("button[type=submit]")
    expect(page.locator("h1")).to_have_text("Your models")

    # ---- create: a tiny configuration, and a broken reward function first
    page.click("text=Create model")
    page.fill("#id_name", "oval-racer")
    page.check("input[name=track_id][value=racecraft_oval]")
    page.fill("#id_gen_max_steering", "30")
    page.fill("#id_gen_steering_levels", "3")
    page.fill("#id_gen_max_speed", "1.5")
    page.fill("#id_gen_speed_levels", "1")
    page.click("#generate-actions")
    expect(page.locator("tr.action-row")).to_have_count(3)
    expect(page.locator("#id_name")).to_have_value("oval-racer")
    page.fill("#id_num_episodes_between_training", "4")
    page.fill("#id_num_epochs", "3")
    page.select_option("#id_batch_size", "32")
    page.fill("#id_max_minutes", "2")
    page.fill("#id_stop_when_ready", "20")  # beside the 2 minutes: never reached here
    set_editor(page, BROKEN)
    page.click("#validate-reward")
    error = page.locator("#reward-result .error-list li").first
    expect(error).to_contain_text("Line 3")
    # The editor marks line 3: a lint marker in the gutter, the line's text underlined.
    expect(page.locator(".cm-lint-marker-error")).to_have_count(1)
    marker_top = page.locator(".cm-lint-marker-error").bounding_box()["y"]
    line3_top = page.locator(
        ".cm-lineNumbers .cm-gutterElement", has_text="3"
    ).first.bounding_box()["y"]
    assert abs(marker_top - line3_top) < 6
    expect(page.locator(".cm-lintRange-error")).to_contain_text("return speed +")
    shot(page, "01-reward-error", "#step-reward")

    set_editor(page, FIXED)
    page.click("#validate-reward")
    expect(page.locator("#reward-result .ok-message")).to_contain_text("Valid")
    page.click("#create-submit")
    expect(page.locator("h1")).to_contain_text("oval-racer")
    expect(page.locator("#config-stop")).to_have_text(
        "2 min, or when ready: 20 evaluations in a row complete every lap"
    )
    shot(page, "02-model-page")

    # ---- train, watch frames arrive and the chart grow without a reload
    page.click("#start-training")
    expect(page.locator("#stop-training")).to_be_visible()
    page.evaluate("window.__sameDocument = true")
    # Playwright's expect, not wait_for_function: the page's CSP forbids evaluating strings.
    expect(page.locator("#training-video")).to_have_attribute(
        "data-frames", re.compile(r"^([3-9]|\d{2,})$"), timeout=180_000
    )
    shot(page, "03-training-video", "#training")
    expect(page.locator("#reward-chart")).to_have_attribute(
        "data-points", re.compile(r"^[1-9]\d*$"), timeout=240_000
    )
    assert page.evaluate("window.__sameDocument === true"), "the page reloaded"
    # "Stop when ready": the live count of evaluations in a row at 100 % (a number, not NaN)
    expect(page.locator("#ready-streak")).to_have_text(re.compile(r"^\d+ of 20$"))
    shot(page, "04-training-chart", "#training")

    stop = page.locator("#stop-training")
    if stop.count() and stop.is_enabled():
        stop.click()  # Stop asks first, in place (no browser dialog)
        confirm = page.locator("#stop-training-confirm")
        if confirm.count():
            expect(confirm).to_contain_text("Yes, stop training")
            shot(page, "05a-stop-confirm", "#training")
            confirm.click()
    expect(page.locator("#job-status")).to_have_text("Completed", timeout=180_000)
    expect(page.locator("#reward-chart")).not_to_have_attribute("data-points", "0")
    shot(page, "05-training-done", "#training")

    # ---- evaluate
    page.select_option("#id_laps", "3")
    page.click("#start-evaluation")
    expect(page.locator("#evaluation-status")).to_be_visible()
    expect(page.locator("#results-table")).to_be_visible(timeout=300_000)
    rows = page.locator("#results-table tbody tr")
    assert 1 <= rows.count() <= 3
    expect(rows.first.locator("td").nth(1)).to_have_text(_laptime_re())
    expect(page.locator("#evaluation-video")).to_be_visible()
    page.locator("#evaluation").scroll_into_view_if_needed()
    shot(page, "06-evaluation", "#evaluation")

    # ---- download the car model
    page.click("summary:has-text('Download')")
    # Built by the training worker at the end: served at once (else a worker builds it first:
    # tests/console/test_background_browser.py).
    with page.expect_download() as info:
        page.click("#download-car")
    download = info.value
    assert download.suggested_filename == "physicalmodel-oval-racer.tar.gz"
    with tarfile.open(fileobj=io.BytesIO(Path(download.path()).read_bytes())) as tar:
        assert {"agent/model.pb", "model_metadata.json"} <= set(tar.getnames())

    # ---- clone (its reward function is validated on the worker first), then delete the clone
    page.click("#clone-link")
    page.fill("#id_name", "oval-racer-2")
    page.click("#clone-submit")
    expect(page.locator("h1")).to_contain_text("oval-racer-2", timeout=180_000)
    page.click("#delete-link")
    shot(page, "07-delete-confirm")
    page.click("#confirm-delete")
    expect(page.locator(".flash")).to_contain_text("deleted")
    expect(page.locator("#models-table tbody tr")).to_have_count(1)
    expect(page.locator("#models-table")).to_contain_text("oval-racer")
    shot(page, "08-models-list")
    assert not page.errors, page.errors
    assert "Traceback" not in log.read_text() or "succeeded" in log.read_text()


def _laptime_re():
    import re

    return re.compile(r"^\d\d:\d\d\.\d{3}$")
