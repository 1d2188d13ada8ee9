"""A car export and a model import in Chromium (issue 10): neither runs in the web request;
the page shows the worker's progress, then offers the car archive or opens the imported
model. daphne and a real Celery worker; the model has a real (untrained) checkpoint."""

from __future__ import annotations

import io
import re
import tarfile
from pathlib import Path

import pytest
from django.contrib.auth import get_user_model

from tests.conftest import PASSWORD
from tests.console.conftest import ACTIONS, make_model
from training.interchange.export import checkpoint_bytes
from training.models import RacingModel
from training.services.downloads import virtual_model_archive
from training.store import get_store, keys_for

pytestmark = [pytest.mark.browser, pytest.mark.slow, pytest.mark.django_db(transaction=True),
              pytest.mark.timeout(600)]  # fmt: skip
WORKER_MS = 180_000
"""How long the page may wait for the worker (ms; a loaded machine is slow)."""


def with_checkpoint(model: RacingModel) -> RacingModel:
    from stable_baselines3 import PPO

    from racing.env import RacingEnv
    from training.rl.policies import policy_kwargs

    env = RacingEnv(model.track_id, action_space=ACTIONS)
    policy = PPO("CnnPolicy", env, policy_kwargs=policy_kwargs(), n_steps=64, batch_size=32,
                 device="cpu", seed=1)  # fmt: skip
    get_store().put_bytes(keys_for(model.pk).best, checkpoint_bytes(policy))
    env.close()
    RacingModel.objects.filter(pk=model.pk).update(has_checkpoint=True)
    model.refresh_from_db()
    return model


def test_a_car_export_and_an_import_run_on_the_worker(browser, daphne, celery_worker,
                                                      store_dir):  # fmt: skip
    from playwright.sync_api import expect

    alice = get_user_model().objects.create_user("alice", password=PASSWORD)
    model = with_checkpoint(make_model(alice))
    context = browser.new_context(accept_downloads=True)
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(f"{daphne.url}/accounts/login/")
    page.fill("#id_username", "alice")
    page.fill("#id_password", PASSWORD)
    page.click("button[type=submit]")
    expect(page).to_have_url(re.compile(r"/models/$"))

    # ---- the car model: a page with the worker's progress, then the download
    page.goto(f"{daphne.url}/models/{model.pk}/")
    page.click("summary:has-text('Download')")
    page.click("#download-car")
    expect(page.locator("#export-progress")).to_be_visible()
    expect(page.locator("#download-ready")).to_be_visible(timeout=WORKER_MS)
    with page.expect_download() as info:
        page.click("#download-ready")
    assert info.value.suggested_filename == "physicalmodel-alice-oval.tar.gz"
    with tarfile.open(fileobj=io.BytesIO(Path(info.value.path()).read_bytes())) as tar:
        assert {"agent/model.pb", "model_metadata.json"} <= set(tar.getnames())

    # ---- an import: stored, imported by the worker, then the model's page
    page.goto(f"{daphne.url}/models/import/")
    page.fill("#id_name", "again")
    page.set_input_files("#id_archive", files=[{
        "name": "m.tar.gz", "mimeType": "application/gzip",
        "buffer": virtual_model_archive(model),
    }])  # fmt: skip
    page.click("button.primary[type=submit]")
    expect(page.locator("#import-progress")).to_be_visible()
    expect(page.locator("h1")).to_contain_text("again", timeout=WORKER_MS)
    expect(page.locator(".flash")).to_contain_text("Model again imported.")
    assert RacingModel.objects.get(owner=alice, name="again").imported
    assert not errors, errors
