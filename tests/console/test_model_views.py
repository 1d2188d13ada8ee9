"""The models pages: who may see what, the create form (errors keep every value), the action
generator, delete with confirmation, import errors and downloads."""

from __future__ import annotations

import html
import json
import re

import pytest
from django.test import Client
from django.utils import timezone

from tests.conftest import PASSWORD
from tests.console.conftest import REWARD, make_model
from training.models import IterationMetric, JobStatus, RacingModel, TrainingJob
from training.selectors import clean_streak
from training.services import rewards

pytestmark = pytest.mark.django_db


def create_data(**overrides) -> dict:
    data = {
        "name": "my-first-model",
        "description": "Round and round",
        "track_id": "racecraft_oval",
        "direction": "native",
        "race_type": "TIME_TRIAL",
        "sensor": "FRONT_FACING_CAMERA",
        "action_space_type": "discrete",
        "action_steering": ["-30", "0", "30"],
        "action_speed": ["1", "1.5", "1"],
        "gen_max_steering": "30",
        "gen_steering_levels": "5",
        "gen_max_speed": "1",
        "gen_speed_levels": "2",
        "steering_low": "-30",
        "steering_high": "30",
        "speed_low": "1",
        "speed_high": "2",
        "algorithm": "clipped_ppo",
        "neural_network": "RACECRAFT_LEAN_CNN",
        "batch_size": "32",
        "num_epochs": "3",
        "lr": "0.0003",
        "beta_entropy": "0.01",
        "sac_alpha": "0.2",
        "discount_factor": "0.999",
        "loss_type": "huber",
        "num_episodes_between_training": "4",
        "reward_function": REWARD,
        "max_minutes": "30",
    }
    data.update(overrides)
    return data


def test_public_pages_and_login_required(client: Client, alice_model) -> None:
    for url in ("/", "/tracks/", "/accounts/login/", "/accounts/signup/"):
        assert client.get(url).status_code == 200, url
    for url in ("/models/", "/models/new/", f"/models/{alice_model.pk}/", "/models/import/"):
        response = client.get(url)
        assert response.status_code == 302 and response["Location"].startswith("/accounts/login/")


def test_sign_up_log_out_and_log_in(client: Client) -> None:
    weak = client.post(
        "/accounts/signup/", {"username": "dana", "password1": "123", "password2": "123"}
    )
    assert weak.status_code == 200 and "too short" in weak.content.decode()
    assert 'value="dana"' in weak.content.decode()
    response = client.post(
        "/accounts/signup/", {"username": "dana", "password1": PASSWORD, "password2": PASSWORD}
    )
    assert response.status_code == 302 and response["Location"] == "/models/"
    assert client.get("/models/").status_code == 200
    assert client.get("/accounts/logout/").status_code == 405  # log out is a POST
    client.post("/accounts/logout/")
    assert client.get("/models/").status_code == 302
    response = client.post("/accounts/login/", {"username": "dana", "password": PASSWORD})
    assert response.status_code == 302


def test_list_shows_only_my_models(alice, charlie, alice_client, store_dir) -> None:
    make_model(alice, "alice-one")
    make_model(charlie, "charlie-secret")
    page = alice_client.get("/models/").content.decode()
    assert "alice-one" in page and "charlie-secret" not in page
    assert "Ready" in page and "Racecraft Oval" in page and "PPO" in page


def test_create_with_errors_keeps_every_value(alice_client, store_dir) -> None:
    data = create_data(
        name="bad name",
        description="Keep this text",
        action_steering=["-30", "45", "30"],
        num_epochs="99",
        max_minutes="2000",
        reward_function="def reward_function(params):\n    return 0.5  # mine\n",
    )
    response = alice_client.post("/models/new/", data)
    assert response.status_code == 400
    page = response.content.decode()
    assert 'value="bad name"' in page and "Keep this text" in page
    assert "Use 1-64 letters, digits or hyphens." in page
    assert 'value="45"' in page and "Steering angle 45 is outside -30..30 degrees." in page
    assert "Ensure this value is less than or equal to 10." in page
    assert "Ensure this value is less than or equal to 1440." in page
    assert "return 0.5  # mine" in html.unescape(page)
    assert not RacingModel.objects.exists()


def test_sac_needs_a_continuous_action_space(alice_client, store_dir) -> None:
    response = alice_client.post("/models/new/", create_data(algorithm="sac"))
    assert response.status_code == 400
    assert "SAC works only with a continuous action space" in response.content.decode()


def test_too_few_actions_and_bad_race_settings_are_refused(alice_client, store_dir) -> None:
    data = create_data(action_steering=["0"], action_speed=["1"], race_type="HEAD_TO_BOT",
                       number_of_bots="9", bot_speed="0.5")  # fmt: skip
    response = alice_client.post("/models/new/", data)
    assert response.status_code == 400
    page = response.content.decode()
    assert "2 to 30 actions; this one has 1" in page
    # the services' rule, on its field, and the typed value kept
    field = re.search(r'id="field-number_of_bots">(.*?)</div>', page, re.S)[1]
    assert "Number_of_bots must be an integer from 1 to 6, not 9" in html.unescape(field)
    assert 'value="9"' in field


@pytest.fixture
def reward_passed(alice) -> None:
    """The form's reward function validated on a worker (the page's way: test_reward_saving)."""
    rewards.reward_validation_remember(
        user_id=alice.pk, source=REWARD, track_id="racecraft_oval", direction="native"
    )


def test_object_avoidance_with_stereo_and_lidar(alice_client, store_dir, reward_passed) -> None:
    """The wizard offers the race types, their settings and the LIDAR; the model keeps them
    and its page shows them."""
    page = alice_client.get("/models/new/").content.decode()
    for words in ('value="OBJECT_AVOIDANCE"', 'value="HEAD_TO_BOT"', 'name="number_of_objects"',
                  'name="object_positions"', 'name="bot_speed"', 'name="bot_lane_change"',
                  'value="SECTOR_LIDAR"', 'data-race="HEAD_TO_BOT"'):  # fmt: skip
        assert words in page, words
    assert "disabled" not in re.search(r'id="step-race">(.*?)</section>', page, re.S)[1]
    bad = create_data(race_type="OBJECT_AVOIDANCE", object_positions="0.2,1;0.25,-1")
    page = alice_client.post("/models/new/", bad).content.decode()
    assert "closer than 0.13 of the track" in page and not RacingModel.objects.exists()
    data = create_data(race_type="OBJECT_AVOIDANCE", number_of_objects="4",
                       object_placement="random", sensor="STEREO_CAMERAS",
                       lidar="LIDAR")  # fmt: skip
    response = alice_client.post("/models/new/", data)
    assert response.status_code == 302, response.content.decode()[:2000]
    model = RacingModel.objects.get()
    assert model.race_type == "OBJECT_AVOIDANCE" and model.sensors == ["STEREO_CAMERAS", "LIDAR"]
    assert model.race_config["number_of_objects"] == 4 and model.race_config["randomize_objects"]
    page = alice_client.get(f"/models/{model.pk}/").content.decode()
    assert "4, placed at random each episode" in page and "Stereo camera, LIDAR" in page


def test_head_to_bot_settings_reach_the_model(alice_client, store_dir, reward_passed) -> None:
    data = create_data(race_type="HEAD_TO_BOT", number_of_bots="3", bot_speed="0.8",
                       bot_lane_change="on", lane_change_min_s="2", lane_change_max_s="4",
                       lidar="SECTOR_LIDAR")  # fmt: skip
    assert alice_client.post("/models/new/", data).status_code == 302
    model = RacingModel.objects.get()
    assert model.sensors == ["FRONT_FACING_CAMERA", "SECTOR_LIDAR"]
    config = model.race_config
    assert (config["number_of_bots"], config["bot_speed"], config["bot_lane_change"]) == (
        3, 0.8, True)  # fmt: skip
    assert (config["lane_change_min_s"], config["lane_change_max_s"]) == (2.0, 4.0)
    page = alice_client.get(f"/models/{model.pk}/").content.decode()
    assert "3 at 0.8 m/s, changing lanes every 2.0-4.0 s" in page
    # camera + sector LIDAR against bots: DeepRacer's advice is stereo cameras with a LIDAR
    assert "recommends stereo cameras with a LIDAR to race against bot cars" in page


def test_reward_errors_are_shown_with_their_lines(alice_client, store_dir) -> None:
    broken = "def reward_function(params):\n    x = params['speed'\n    return x\n"
    response = alice_client.post("/models/new/", create_data(reward_function=broken))
    assert response.status_code == 400
    page = response.content.decode()
    errors = json.loads(
        re.search(r'<script id="reward-errors" type="application/json">(.*?)</script>', page)[1]
    )
    assert errors and errors[0]["type"] == "SYNTAX_ERROR" and errors[0]["lineNumber"] == 2
    assert "params[&#x27;speed&#x27;" in page  # the source is kept
    assert 'data-jump="step-reward"' in page  # the page reopens at the editor, not the top


def test_create_discrete_and_continuous(alice, alice_client, store_dir) -> None:
    # Validated on a worker first (the page's way there: tests/console/test_reward_saving.py).
    rewards.reward_validation_remember(
        user_id=alice.pk, source=REWARD, track_id="racecraft_oval", direction="native"
    )
    response = alice_client.post("/models/new/", create_data())
    model = RacingModel.objects.get(owner=alice, name="my-first-model")
    assert response.status_code == 302 and response["Location"] == f"/models/{model.pk}/"
    assert [a["steering_angle"] for a in model.action_space] == [-30, 0, 30]
    assert model.hyperparameters["batch_size"] == 32 and model.max_minutes == 30
    assert model.sensors == ["FRONT_FACING_CAMERA"] and model.description == "Round and round"

    data = create_data(name="smooth", action_space_type="continuous", algorithm="sac",
                       sensor="STEREO_CAMERAS", speed_low="0.5", speed_high="3")  # fmt: skip
    assert alice_client.post("/models/new/", data).status_code == 302
    smooth = RacingModel.objects.get(owner=alice, name="smooth")
    assert smooth.algorithm == "sac" and smooth.action_space_type == "continuous"
    assert smooth.action_space["speed"] == {"low": 0.5, "high": 3.0}
    assert smooth.sensors == ["STEREO_CAMERAS"]
    page = alice_client.get(f"/models/{smooth.pk}/").content.decode()
    assert "SAC" in page and "Stereo camera" in page and "Start training" in page


def test_duplicate_name_is_shown_on_the_name_field(alice, alice_client, store_dir) -> None:
    make_model(alice, "taken")
    page = alice_client.post("/models/new/", create_data(name="taken")).content.decode()
    assert "You already have a model named" in page


def test_the_generator_fills_the_table_and_keeps_the_rest(alice_client, store_dir) -> None:
    data = create_data(name="keep-me", gen_max_steering="20", gen_steering_levels="3",
                       gen_max_speed="2", gen_speed_levels="2", generate="1")  # fmt: skip
    response = alice_client.post("/models/new/", data)
    page = response.content.decode()
    assert response.status_code == 200 and 'value="keep-me"' in page
    steering = re.findall(r'name="action_steering" value="([^"]+)"', page)
    speeds = re.findall(r'name="action_speed" value="([^"]+)"', page)
    assert steering == ["-20", "-20", "0", "0", "20", "20"]
    assert speeds == ["1", "2", "1", "2", "1", "2"]
    too_many = alice_client.post("/models/new/", {**data, "gen_steering_levels": "15",
                                                  "gen_speed_levels": "3"})  # fmt: skip
    assert "45 actions" in too_many.content.decode()
    assert not RacingModel.objects.exists()


def test_others_get_404_for_pages_actions_and_downloads(alice_model, charlie_client) -> None:
    pk = alice_model.pk
    for url in (f"/models/{pk}/", f"/models/{pk}/clone/", f"/models/{pk}/delete/",
                f"/models/{pk}/download/car/", f"/models/{pk}/download/virtual/",
                f"/models/{pk}/download/logs/"):  # fmt: skip
        assert charlie_client.get(url).status_code == 404, url
    for url in (f"/models/{pk}/delete/", f"/models/{pk}/train/", f"/models/{pk}/evaluate/"):
        assert charlie_client.post(url).status_code == 404, url
    assert RacingModel.objects.filter(pk=pk).exists()


def test_delete_asks_first(alice_model, alice_client) -> None:
    page = alice_client.get(f"/models/{alice_model.pk}/delete/").content.decode()
    assert "Delete alice-oval?" in page and "cannot be undone" in page
    response = alice_client.post(f"/models/{alice_model.pk}/delete/")
    assert response.status_code == 302 and response["Location"] == "/models/"
    assert not RacingModel.objects.filter(pk=alice_model.pk).exists()


def test_downloads_need_a_checkpoint(alice_model, alice_client) -> None:
    response = alice_client.get(f"/models/{alice_model.pk}/download/car/", follow=True)
    assert "no trained checkpoint yet" in response.content.decode()
    assert alice_client.get(f"/models/{alice_model.pk}/download/nope/").status_code == 404


def test_import_errors_are_clear(alice, alice_client, store_dir) -> None:
    missing = alice_client.post("/models/import/", {"name": "imported"})
    assert missing.status_code == 400
    assert "Choose a model archive to upload." in missing.content.decode()
    from django.core.files.uploadedfile import SimpleUploadedFile

    taken = SimpleUploadedFile("model.tar.gz", b"an archive", "application/gzip")
    make_model(alice, "imported")
    response = alice_client.post("/models/import/", {"name": "imported", "archive": taken})
    assert response.status_code == 400  # what is cheap to check is answered at once
    page = response.content.decode()
    assert 'value="imported"' in page and "field-error" in page and "already have" in page
    # The archive itself is read by a worker (tests/training/services/test_background.py):
    junk = SimpleUploadedFile("model.tar.gz", b"not an archive at all", "application/gzip")
    response = alice_client.post("/models/import/", {"name": "other", "archive": junk})
    assert response.status_code == 302 and "?task=" in response["Location"]
    page = alice_client.get(response["Location"]).content.decode()
    assert 'id="import-progress"' in page and "data-background-poll" in page
    assert not RacingModel.objects.filter(name="other").exists()


def test_start_training_and_stop_it(alice_model, alice_client, monkeypatch,
                                    django_capture_on_commit_callbacks) -> None:  # fmt: skip
    from training import dispatch

    queued = []
    monkeypatch.setattr(dispatch, "send", lambda name, pk: queued.append(pk) or "t")
    with django_capture_on_commit_callbacks(execute=True):
        response = alice_client.post(f"/models/{alice_model.pk}/train/")
    assert response.status_code == 302
    job = alice_model.training_jobs.get()
    assert queued == [job.pk]
    page = alice_client.get(f"/models/{alice_model.pk}/").content.decode()
    assert "Stop training" in page and "Queued" in page
    again = alice_client.post(f"/models/{alice_model.pk}/train/", follow=True)
    assert "busy" in again.content.decode()
    alice_client.post(f"/jobs/training/{job.pk}/stop/")
    job.refresh_from_db()
    assert job.status == "CANCELED"


def test_evaluate_form_errors(alice_model, alice_client) -> None:
    response = alice_client.post(
        f"/models/{alice_model.pk}/evaluate/",
        {"track_id": "racecraft_oval", "direction": "native", "laps": "7",
         "off_track_penalty_s": "-1", "crash_penalty_s": "5"},
    )  # fmt: skip
    page = response.content.decode()
    assert response.status_code == 400
    assert "Select a valid choice. 7 is not one of the available choices." in page
    assert "greater than or equal to 0" in page
    ok = alice_client.post(
        f"/models/{alice_model.pk}/evaluate/",
        {"track_id": "racecraft_oval", "direction": "native", "laps": "3",
         "off_track_penalty_s": "2", "crash_penalty_s": "5"},
    )  # fmt: skip
    assert ok.status_code == 400 and "Train this model before evaluating it" in ok.content.decode()


def test_evaluate_in_another_race_with_its_settings(alice, alice_client, store_dir) -> None:
    """The evaluation form offers the race types and their settings, starting from the
    model's own race; the services' rules answer bad settings on their field."""
    model = make_model(alice, race_type="OBJECT_AVOIDANCE",
                       race_config={"number_of_objects": 4, "randomize_objects": True})  # fmt: skip
    RacingModel.objects.filter(pk=model.pk).update(has_checkpoint=True)
    page = alice_client.get(f"/models/{model.pk}/").content.decode()
    form = re.search(r'id="evaluate-form"(.*?)</form>', page, re.S)[1]
    assert '<option value="OBJECT_AVOIDANCE" selected>' in form
    assert re.search(r'name="number_of_objects" value="4"', form)
    assert '<option value="random" selected>' in form
    common = {"track_id": "racecraft_oval", "direction": "native", "laps": "3",
              "off_track_penalty_s": "2", "crash_penalty_s": "5"}  # fmt: skip
    bad = alice_client.post(f"/models/{model.pk}/evaluate/",
                            {**common, "race_type": "HEAD_TO_BOT", "bot_speed": "7"})  # fmt: skip
    assert bad.status_code == 400
    field = re.search(r'id="field-bot_speed">(.*?)</div>', bad.content.decode(), re.S)[1]
    assert "Bot_speed must be 0.2-6.0 m/s, not 7.0" in html.unescape(field)
    ok = alice_client.post(
        f"/models/{model.pk}/evaluate/",
        {**common, "race_type": "HEAD_TO_BOT", "number_of_bots": "3", "bot_speed": "1.5"},
    )
    assert ok.status_code == 302
    job = model.evaluations.get()
    assert job.race_type == "HEAD_TO_BOT" and job.race_config["number_of_bots"] == 3
    assert job.race_config["bot_speed"] == 1.5


def test_stop_when_ready_is_set_shown_kept_by_a_clone_and_checked(
    alice, alice_client, store_dir
) -> None:
    rewards.reward_validation_remember(
        user_id=alice.pk, source=REWARD, track_id="racecraft_oval", direction="native"
    )
    response = alice_client.post("/models/new/", create_data(stop_when_ready="21"))
    assert response.status_code == 400
    assert "Ensure this value is less than or equal to 20." in response.content.decode()
    assert not RacingModel.objects.exists()

    assert alice_client.post("/models/new/", create_data(stop_when_ready="")).status_code == 302
    assert RacingModel.objects.get(name="my-first-model").stop_when_ready == 0  # empty: off

    response = alice_client.post("/models/new/", create_data(name="ready", stop_when_ready="3"))
    model = RacingModel.objects.get(owner=alice, name="ready")
    assert response.status_code == 302 and model.stop_when_ready == 3
    page = alice_client.get(f"/models/{model.pk}/").content.decode()
    stop = "30 min, or when ready: 3 evaluations in a row complete every lap"
    assert re.search(r'id="config-stop">' + re.escape(stop) + "<", page)
    assert "or until 3 evaluations in a row complete every lap" in page

    form = alice_client.get(f"/models/{model.pk}/clone/").content.decode()
    assert re.search(r'name="stop_when_ready" value="3"', form)
    data = {"name": "ready-clone", "description": "", "track_id": "racecraft_oval",
            "direction": "native", "reward_function": REWARD, "max_minutes": "20",
            "stop_when_ready": "2"}  # fmt: skip
    assert alice_client.post(f"/models/{model.pk}/clone/", data).status_code == 302
    assert RacingModel.objects.get(name="ready-clone").stop_when_ready == 2


def test_a_job_that_ended_ready_says_so(alice_model, alice_client) -> None:
    now = timezone.now()
    TrainingJob.objects.create(model=alice_model, max_minutes=60, stop_when_ready=3,
                               status=JobStatus.COMPLETED, stopped_by="ready", iterations=12,
                               best_iteration=12, started_at=now, finished_at=now)  # fmt: skip
    page = alice_client.get(f"/models/{alice_model.pk}/").content.decode()
    assert re.search(r'id="job-stop-condition" title="60 min, or when ready: 3 evaluations in a '
                     r'row complete every lap">60 min or ready \(3 in a row\)<', page)  # fmt: skip
    ended = (
        'id="job-stopped-by" title="3 evaluations in a row completed every lap; iteration 12 '
        'is the best checkpoint">Ready at iteration 12<'
    )
    assert ended in page
    assert re.search(r'id="ready-streak" data-needed="3" data-streak="0">0 of 3<', page)


def test_the_ready_streak_counts_the_latest_evaluations_at_100_percent(
    alice_model, alice_client
) -> None:
    job = TrainingJob.objects.create(model=alice_model, max_minutes=60, stop_when_ready=5,
                                     status=JobStatus.IN_PROGRESS)  # fmt: skip
    for i, progress in enumerate([100.0, 100.0, 40.0, 100.0, 100.0], start=1):
        IterationMetric.objects.create(job=job, iteration=i, episodes=4, steps=100,
                                       total_steps=100 * i, train_reward=1.0, train_progress=50.0,
                                       eval_progress=progress, elapsed_s=10.0 * i)  # fmt: skip
    page = alice_client.get(f"/models/{alice_model.pk}/").content.decode()
    assert re.search(r'id="ready-streak" data-needed="5" data-streak="2">2 of 5<', page)
    assert clean_streak([]) == 0
    assert clean_streak([{"eval_progress": 100.0}, {"eval_progress": 99.99}]) == 0
