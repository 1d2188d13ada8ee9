# ruff: noqa: E501 - the page scripts and the table of page groups read best unwrapped
"""Every page group at a phone's width (390 px), a laptop's (1280) and a wide screen's (1920) in
Chromium: nothing that should stand apart overlaps (the bounding boxes of the main cards,
videos and tables are compared), the page never scrolls sideways, and the browser's console
stays free of errors. Screenshots: test-artifacts/browser/layout/<group>-<width>.png.

One site for the whole module, to keep this quick: daphne on the test database, and one
"trained" model shared by every group (a READY model with a checkpoint flag, a finished training
job with its reward graph, an evaluation with laps and a real MP4; a second model in the middle
of training; a league event with a ranked submission). No training or evaluation runs here:
tests/console/test_console_browser.py drives those for real.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import timedelta
from pathlib import Path
from unittest import mock

import numpy as np
import pytest

from tests.support import celery_worker_process, daphne_process, database_url

ROOT = Path(__file__).resolve().parents[2]
ARTIFACTS = ROOT / "test-artifacts" / "browser" / "layout"
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--no-first-run"]  # fmt: skip
WIDTHS = (390, 1280, 1920)
PASSWORD = "pw-racer-123"  # league_helpers.make_user's
REWARD = "def reward_function(params):\n    return 1.0\n"
ACTIONS = [{"steering_angle": a, "speed": 1.0} for a in (-30, 0, 30)]

pytestmark = [
    pytest.mark.browser,
    pytest.mark.slow,
    pytest.mark.timeout(600),
    pytest.mark.skipif(not Path(CHROMIUM).exists(), reason="apt-get install -y chromium"),
]

# Pairs of these boxes must not overlap unless one holds the other.
OVERLAPS_JS = """
(selectors) => {
  // What shows of an element: its box clipped by every ancestor that scrolls or clips it (a wide
  // table inside a card that scrolls sideways is fine; the card must fit), on both axes (a
  // scroll box's options scrolled out of it are not drawn; a box that scrolls one axis clips
  // both).
  const visible = (el) => {
    let r = el.getBoundingClientRect();
    let box = { left: r.left, right: r.right, top: r.top, bottom: r.bottom };
    for (let p = el.parentElement; p && p !== document.body; p = p.parentElement) {
      const o = getComputedStyle(p).overflowX;
      if (o === "auto" || o === "scroll" || o === "hidden") {
        const q = p.getBoundingClientRect();
        box = { left: Math.max(box.left, q.left), right: Math.min(box.right, q.right),
                top: Math.max(box.top, q.top), bottom: Math.min(box.bottom, q.bottom) };
      }
    }
    box.width = box.right - box.left;
    box.height = box.bottom - box.top;
    return box;
  };
  const boxes = [];
  for (const selector of selectors) {
    for (const el of document.querySelectorAll(selector)) {
      const r = visible(el);
      const style = getComputedStyle(el);
      if (r.width < 1 || r.height < 1 || style.visibility === "hidden") continue;
      // A closed <details> shows only its summary: what it holds is not drawn.
      const closed = el.parentElement && el.parentElement.closest("details:not([open])");
      if (closed && !el.matches("details")) continue;
      boxes.push({ el, r, name: selector + (el.id ? "#" + el.id : "") });
    }
  }
  const found = [];
  for (let i = 0; i < boxes.length; i++) {
    const a = boxes[i];
    if (a.r.right > window.innerWidth + 1 || a.r.left < -1) {
      found.push(`${a.name} leaves the viewport (${a.r.left.toFixed(0)}..${a.r.right.toFixed(0)} px)`);
    }
    for (let j = i + 1; j < boxes.length; j++) {
      const b = boxes[j];
      if (a.el === b.el || a.el.contains(b.el) || b.el.contains(a.el)) continue;
      const w = Math.min(a.r.right, b.r.right) - Math.max(a.r.left, b.r.left);
      const h = Math.min(a.r.bottom, b.r.bottom) - Math.max(a.r.top, b.r.top);
      if (w > 1 && h > 1) found.push(`${a.name} overlaps ${b.name} by ${w.toFixed(0)}×${h.toFixed(0)} px`);
    }
  }
  return found;
}
"""


@dataclass(frozen=True)
class Site:
    url: str
    trained: int  # a trained and evaluated model
    live: int  # a model in the middle of training
    fresh: int  # a model never trained
    event: int
    submission: int


def _mp4() -> bytes:
    from training.rl.evaluation import VideoWriter

    video = VideoWriter()
    for i in range(15):
        chase = np.full((240, 320, 3), 40 + i * 8, dtype=np.uint8)
        video.add(chase, np.full((120, 160), 200, dtype=np.uint8))
    data = video.finish()
    assert data
    return data


def _populate() -> dict:
    from django.utils import timezone

    from leaderboard.services import submission_create
    from tests.leaderboard.league_helpers import finish_evaluation, lap, make_event, make_user
    from training import services
    from training.models import (
        EvaluationJob,
        IterationMetric,
        JobStatus,
        RacingModel,
        TrainingJob,
    )
    from training.store import get_store, keys_for

    now = timezone.now()
    racer = make_user("racer", alias="Racer-One")
    store, video = get_store(), _mp4()

    def model(name: str) -> RacingModel:
        return services.model_create(owner=racer, name=name, track_id="racecraft_oval",
                                     action_space=ACTIONS, reward_function=REWARD, seed=1,
                                     max_minutes=2, validate_reward=False)  # fmt: skip

    def metrics(job: TrainingJob, n: int) -> None:
        IterationMetric.objects.bulk_create(
            IterationMetric(job=job, iteration=i, episodes=4, steps=400, total_steps=400 * i,
                            train_reward=10 + 4 * i, train_progress=min(100, 12 * i),
                            eval_progress=min(100, 14 * i), is_best=i == n, elapsed_s=15.0 * i)
            for i in range(1, n + 1)
        )  # fmt: skip

    trained = model("oval-racer")
    RacingModel.objects.filter(pk=trained.pk).update(has_checkpoint=True)
    trained.refresh_from_db()
    job = TrainingJob.objects.create(
        model=trained, max_minutes=2, status=JobStatus.COMPLETED, iterations=8, episodes=32,
        started_at=now - timedelta(minutes=3), finished_at=now - timedelta(minutes=1),
        best_iteration=8, best_eval_progress=100.0, stopped_by="time_limit",
    )  # fmt: skip
    metrics(job, 8)
    for number, laps in enumerate(([lap(36.1), lap(3.0, "off_track")], [lap(34.4), lap(34.6),
                                   lap(34.5, off_tracks=1)]), 1):  # fmt: skip
        evaluation = EvaluationJob.objects.create(
            model=trained, track_id="racecraft_oval", laps=3, status=JobStatus.COMPLETED,
            started_at=now - timedelta(seconds=60 - number), finished_at=now,
            created_at=now - timedelta(seconds=60 - number),
            results={"laps": [dict(r, trial=i) for i, r in enumerate(laps, 1)],
                     "completed_laps": sum(r["status"] == "lap_complete" for r in laps)},
            laps_done=len(laps), has_video=True,
        )  # fmt: skip
        store.put_bytes(keys_for(trained.pk).video(evaluation.pk), video, "video/mp4")

    live = model("oval-live")
    RacingModel.objects.filter(pk=live.pk).update(status=RacingModel.Status.TRAINING)
    running = TrainingJob.objects.create(model=live, max_minutes=2, status=JobStatus.IN_PROGRESS,
                                         started_at=now - timedelta(seconds=50), heartbeat_at=now)  # fmt: skip
    metrics(running, 2)

    fresh = model("oval-fresh")
    event = make_event(racer, name="Oval sprint", min_laps=1)
    with mock.patch("training.dispatch.send", return_value="t"):
        submission = submission_create(event=event, user=racer, model=trained)
    finish_evaluation(submission.evaluation, [lap(34.4), lap(34.6), lap(34.5)])
    type(submission.evaluation).objects.filter(pk=submission.evaluation_id).update(has_video=True)
    store.put_bytes(keys_for(trained.pk).video(submission.evaluation_id), video, "video/mp4")
    return {"trained": trained.pk, "live": live.pk, "fresh": fresh.pk, "event": event.pk,
            "submission": submission.pk}  # fmt: skip


@pytest.fixture
def site(redis_env, tmp_path, settings) -> Iterator[Site]:
    from django.core.management import call_command

    settings.STORE_DIR = tmp_path / "store"
    settings.RACECRAFT_TRACKS_DIR = tmp_path / "tracks"
    call_command("build_assets")
    ids = _populate()
    env = {**os.environ, **redis_env, "DATABASE_URL": database_url(), "DEBUG": "1",
           "STORE_DIR": str(settings.STORE_DIR), "DJANGO_SETTINGS_MODULE": "console.settings",
           "RACECRAFT_TRACKS_DIR": str(settings.RACECRAFT_TRACKS_DIR)}  # fmt: skip
    # The shared servers of tests/support.py: daphne, and a worker for the quick queue, where
    # reward validation runs (the web process runs no reward code).
    with (
        daphne_process(env=env, log_path=tmp_path / "daphne.log") as server,
        celery_worker_process(queues=["interactive"], env=env, log_path=tmp_path / "worker.log"),
    ):
        yield Site(url=server.url, **ids)


@pytest.fixture
def browser_page(site: Site):
    from playwright.sync_api import sync_playwright

    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        context = browser.new_context(viewport={"width": 1280, "height": 900})
        context.set_default_timeout(30_000)
        page = context.new_page()
        page.console_errors = []
        page.on("console", lambda m: m.type == "error" and page.console_errors.append(m.text))
        page.on("pageerror", lambda e: page.console_errors.append(str(e)))
        page.goto(f"{site.url}/accounts/login/")
        page.fill("#id_username", "racer")
        page.fill("#id_password", PASSWORD)
        page.click("button[type=submit]")
        page.wait_for_url(f"{site.url}/models/")  # a login lands on the models
        try:
            yield page
        finally:
            browser.close()


def check_layout(page, url: str, group: str, selectors: list[str], ready: str = "") -> None:
    """Load ``url`` at each width: screenshot, overlaps, sideways scrolling, console errors."""
    problems = []
    page.console_errors.clear()
    for width in WIDTHS:
        page.set_viewport_size({"width": width, "height": 900})
        page.goto(url)
        page.wait_for_load_state("load")
        if ready:
            page.wait_for_selector(ready)
        page.wait_for_timeout(300)  # fonts, the chart's first draw
        page.evaluate("window.scrollTo(0, 0)")  # the sticky bar stays on top of the shot
        page.screenshot(path=str(ARTIFACTS / f"{group}-{width}.png"), full_page=True)
        problems += [f"{width} px: {p}" for p in page.evaluate(OVERLAPS_JS, selectors)]
        sideways = page.evaluate("document.documentElement.scrollWidth - window.innerWidth")
        if sideways > 1:
            problems.append(f"{width} px: the page scrolls sideways by {sideways} px")
    assert not problems, "\n".join(problems)
    assert not page.console_errors, page.console_errors


def groups(site: Site) -> list[tuple[str, str, list[str], str]]:
    """(group, url, boxes that must stand apart, what to wait for)."""
    u = site.url
    return [
        ("models-list", f"{u}/models/", [".page-head > *", ".table-card", "#models-table tbody tr"], ""),
        ("create", f"{u}/models/new/", [".page-head", ".stepper", ".wizard > .panel", ".option",
                                        ".field"], ".reward-editor"),
        ("model-training", f"{u}/models/{site.live}/", [".page-head > *", ".panel", ".stats > div",
         ".chart-card", ".video-card", ".frame"], "#training-video"),
        ("model-trained", f"{u}/models/{site.trained}/", [".page-head > *", ".panel", ".stats > div",
         ".chart-card", ".config-grid > *"], "#reward-chart"),
        ("evaluation", f"{u}/models/{site.trained}/#evaluation", ["#evaluation .eval-form",
         "#evaluation .eval-results > *", "#results-table", "#evaluation-video",
         "#evaluation .field"], "#results-table"),
        ("league-event", f"{u}/league/events/{site.event}/", [".lb-head > *", ".lb-panel",
         ".lb-table", ".lb-facts > div"], ""),
        ("submission", f"{u}/league/submissions/{site.submission}/", [".lb-head > *", ".lb-panel",
         "video", ".lb-table", ".lb-facts > div"], "video"),
        ("reward-edit", f"{u}/models/{site.fresh}/reward/", [".page-head", ".panel",
         ".editor-toolbar > *"], ".reward-editor"),
        ("tracks", f"{u}/tracks/", [".page-head > *", ".track-card", ".track-import",
         ".import-grid .field"], ""),
    ]  # fmt: skip


@pytest.mark.django_db(transaction=True)
def test_every_page_group_at_three_widths_then_validate_and_import_a_track(
    site: Site, browser_page, tmp_path
) -> None:
    """One browser and one server for both checks (each costs a site: daphne, a worker, the
    data and Chromium): the layout of every group, then the pages that act."""
    layout_is_right(site, browser_page)
    validate_shows_progress_and_a_track_file_is_previewed_then_imported(
        site, browser_page, tmp_path
    )


def layout_is_right(site: Site, browser_page) -> None:
    """Every group is checked and reported even when an earlier one fails."""
    failures = []
    for group, url, boxes, ready in groups(site):
        try:
            check_layout(browser_page, url, group, boxes, ready)
        except AssertionError as exc:
            failures.append(f"[{group}]\n{exc}")
    page = browser_page
    page.set_viewport_size({"width": 1280, "height": 900})
    page.goto(f"{site.url}/models/{site.trained}/")
    if page.locator("#training-video").count():
        failures.append("[model-trained] an empty video box after training")
    heading = page.locator("#evaluation h3").first.inner_text()
    if not heading.startswith("Evaluation #2"):
        failures.append(f"[evaluation] numbered {heading!r}, not per model")
    page.goto(f"{site.url}/league/submissions/{site.submission}/")
    if "Lap complete" not in page.locator("#laps").inner_text():
        failures.append("[submission] lap status is not 'Lap complete'")
    assert not failures, "\n\n".join(failures)


def validate_shows_progress_and_a_track_file_is_previewed_then_imported(
    site: Site, browser_page, tmp_path
) -> None:
    import io

    from playwright.sync_api import expect

    from racing.tracks import TrackCatalog

    page = browser_page
    page.goto(f"{site.url}/models/{site.fresh}/reward/")
    page.click("#validate-reward")
    expect(page.locator(".validate-progress")).to_contain_text("Running your function")
    expect(page.locator("#reward-result .ok-message")).to_contain_text("Valid", timeout=60_000)

    # Create refused by the server: the page comes back at the reward editor, not at the top.
    page.goto(f"{site.url}/models/new/")
    page.fill("#id_name", "refused-one")
    page.click("#reward-editor .cm-content")
    page.keyboard.press("Control+a")
    page.keyboard.press("Delete")
    page.keyboard.insert_text("def reward_function(params):\n    return params['nope']\n")
    page.click("#create-submit")
    expect(page.locator("#reward-result .error-list li").first).to_contain_text("Line 2")
    expect(page.locator("#reward-result .error-list li").first).to_contain_text(
        "in all 6 test situations"
    )
    assert page.evaluate("window.scrollY") > 500
    top = page.locator("#step-reward").bounding_box()["y"]
    assert -50 < top < 400, top  # the editor's section is on screen
    page.screenshot(path=str(ARTIFACTS / "create-refused-1280.png"))
    page.console_errors.clear()  # the refused form answers 400, as it should

    buffer = io.BytesIO()
    np.save(buffer, TrackCatalog().load("racecraft_oval").to_array())
    path = tmp_path / "my oval.npy"
    path.write_bytes(buffer.getvalue())
    page.goto(f"{site.url}/tracks/")
    page.set_input_files("#id_file", str(path))
    page.fill("#id_name", "My oval")
    page.click("#track-preview-button")
    expect(page.locator("#track-upload-preview")).to_be_visible()
    page.evaluate("window.scrollTo(0, 0)")
    page.screenshot(path=str(ARTIFACTS / "tracks-preview-1280.png"), full_page=True)
    page.click("#track-import-button")
    expect(page.locator("#track-my_oval")).to_contain_text("My oval")
    assert not page.console_errors, page.console_errors
