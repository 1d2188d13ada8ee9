"""The whole console in Chromium: sign up, create a model (a broken reward function first),
train it with a real Celery worker while watching video and the chart, stop, evaluate,
download the car model, clone and delete. The web server is daphne (HTTP + websockets) in a
subprocess on the test database; screenshots go to test-artifacts/browser/."""

from __future__ import annotations

import io
import os
import socket
import subprocess
import sys
import tarfile
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.support import database_url, free_port

ROOT = Path(__file__).resolve().parents[2]
ARTIFACTS = ROOT / "test-artifacts" / "browser"
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--no-first-run"]  # fmt: skip
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
def child_env(tmp_path, redis_env, settings) -> dict[str, str]:
    settings.STORE_DIR = tmp_path / "store"
    return {**os.environ, **redis_env, "DATABASE_URL": database_url(),
            "STORE_DIR": str(settings.STORE_DIR), "DEBUG": "1",
            "RACECRAFT_TRACKS_DIR": str(settings.RACECRAFT_TRACKS_DIR),
            "DJANGO_SETTINGS_MODULE": "console.settings"}  # fmt: skip


def _stop(proc: subprocess.Popen) -> None:
    proc.terminate()
    try:
        proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()


@pytest.fixture
def worker(child_env, tmp_path) -> Iterator[Path]:
    log_path = tmp_path / "worker.log"
    with open(log_path, "w") as log:
        proc = subprocess.Popen(
            [sys.executable, "-m", "celery", "-A", "console", "worker", "-Q",
             "training,evaluation,default", "-c", "1", "-n", f"browser-{uuid.uuid4().hex[:8]}@%h",
             "--without-gossip", "--without-mingle", "-l", "INFO"],
            cwd=ROOT, env=child_env, stdout=log, stderr=subprocess.STDOUT,
        )  # fmt: skip
        try:
            from console.celery import app

            deadline = time.monotonic() + 60
            while not app.control.ping(timeout=1.0):
                assert proc.poll() is None, log_path.read_text()
                assert time.monotonic() < deadline, "the Celery worker did not answer"
            yield log_path
        finally:
            _stop(proc)


@pytest.fixture
def web(child_env, tmp_path) -> Iterator[str]:
    from django.core.management import call_command

    call_command("build_assets")  # the CodeMirror bundle (npm ci + esbuild when missing)
    port = free_port()
    log_path = tmp_path / "daphne.log"
    with open(log_path, "w") as log:
        proc = subprocess.Popen(
            [sys.executable, "-m", "daphne", "-b", "127.0.0.1", "-p", str(port),
             "console.asgi:application"],
            cwd=ROOT, env=child_env, stdout=log, stderr=subprocess.STDOUT,
        )  # fmt: skip
        try:
            deadline = time.monotonic() + 60
            while True:
                assert proc.poll() is None, log_path.read_text()
                assert time.monotonic() < deadline, "daphne did not start"
                with socket.socket() as s:
                    if s.connect_ex(("127.0.0.1", port)) == 0:
                        break
                time.sleep(0.2)
            yield f"http://127.0.0.1:{port}"
        finally:
            _stop(proc)
            (ARTIFACTS / "daphne.log").write_text(log_path.read_text())


@pytest.fixture
def page(web):
    from playwright.sync_api import sync_playwright

    if not Path(CHROMIUM).exists():
        pytest.skip("Debian's chromium is not installed (apt-get install -y chromium)")
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        context = browser.new_context(
            viewport={"width": 1360, "height": 900}, accept_downloads=True
        )
        context.set_default_timeout(30_000)
        page = context.new_page()
        page.errors = []
        page.on("pageerror", lambda e: page.errors.append(str(e)))
        try:
            yield page
        finally:
            page.screenshot(path=str(ARTIFACTS / "last.png"), full_page=True)
            browser.close()


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


def test_sign_up_create_train_watch_stop_evaluate_download_clone_delete(page, web, worker):
    from playwright.sync_api import expect

    log = worker
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
    shot(page, "02-model-page")

    # ---- train, watch frames arrive and the chart grow without a reload
    page.click("#start-training")
    expect(page.locator("#stop-training")).to_be_visible()
    page.evaluate("window.__sameDocument = true")
    page.wait_for_function(
        "Number(document.getElementById('training-video').dataset.frames) >= 3", timeout=180_000
    )
    shot(page, "03-training-video", "#training")
    page.wait_for_function(
        "Number(document.getElementById('reward-chart').dataset.points) >= 1", timeout=240_000
    )
    assert page.evaluate("window.__sameDocument === true"), "the page reloaded"
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
    with page.expect_download() as info:
        page.click("#download-car")
    download = info.value
    assert download.suggested_filename == "oval-racer-car.tar.gz"
    with tarfile.open(fileobj=io.BytesIO(Path(download.path()).read_bytes())) as tar:
        assert {"model.onnx", "model_metadata.json"} <= set(tar.getnames())

    # ---- clone, then delete the clone
    page.click("#clone-link")
    page.fill("#id_name", "oval-racer-2")
    page.click("#clone-submit")
    expect(page.locator("h1")).to_contain_text("oval-racer-2")
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
