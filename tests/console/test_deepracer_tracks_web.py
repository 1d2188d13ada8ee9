"""DeepRacer's built-in tracks on the web: the Tracks page lists them by console name and
searches and filters them (a GET form), the wizard's pickers carry what the script filters on,
and a model on re:Invent 2018 is made with the racing preset from the wizard, and trains,
with no import."""

from __future__ import annotations

import re

import pytest

from racing.tracks import DEEPRACER_DIR, deepracer_manifest
from tests.console.test_model_views import create_data
from training.models import RacingModel, TrackFile
from training.rewards.examples import example_source
from training.rl.hyperparams import parse_hyperparameters
from training.rl.presets import RACING
from training.rl.runner import TrainingConfig, TrainingHooks, train
from training.services import rewards
from training.worker.common import env_spec

pytestmark = pytest.mark.django_db
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
TOTAL = 3 + len(list(DEEPRACER_DIR.glob("*.npy")))


def card_ids(page: str) -> list[str]:
    return re.findall(r'<li class="track-card" id="track-([^"]+)"', page)


@pytest.fixture
def tracks_dir(tmp_path, settings):
    settings.RACECRAFT_TRACKS_DIR = tmp_path / "tracks"
    return settings.RACECRAFT_TRACKS_DIR


def test_the_tracks_page_lists_deepracers_tracks_by_console_name(client, tracks_dir) -> None:
    page = client.get("/tracks/").content.decode()
    assert len(card_ids(page)) == TOTAL and f"{TOTAL} tracks available" in page
    for name in ("re:Invent 2018", "Ace Speedway", "Kumo Torakku Training", "Smile Speedway",
                 "2022 re:Invent Championship", "Forever Raceway (clockwise)"):  # fmt: skip
        assert f"<h2>{name}</h2>" in page, name
    card = page[page.index('id="track-reinvent_base"') :].split("</li>", 1)[0]
    assert "DeepRacer 2018" in card and "17.71 m" in card and "0.76 m" in card
    assert "Counter-clockwise" in card and 'data-season="2018"' in card
    assert "js/track_filter.js" in page and "css/track_filter.css" in page
    response = client.get("/tracks/reinvent_base.png")
    assert response.status_code == 200 and response.content.startswith(PNG_SIGNATURE)


@pytest.mark.parametrize(
    ("query", "expected"),
    [
        ("f-q=reinvent+2018", {"reinvent_base", "reinvent_carpet", "reinvent_concrete",
                               "reinvent_wood"}),
        ("f-q=REINVENT_BASE", {"reinvent_base"}),  # the id, any case
        ("f-season=2022&f-direction=cw", {"2022_reinvent_champ_cw"}),
        ("f-season=2024", {"2024_reinvent_champ_cw", "2024_reinvent_champ_ccw"}),
        ("f-source=racecraft", {"racecraft_oval", "racecraft_summit", "racecraft_technical"}),
        ("f-direction=open", {"Straight_track"}),
        ("f-min_length=80", {"penbay_pro"}),
        ("f-source=deepracer&f-max_length=17.5",
            {"Bowtie_track", "reInvent2019_wide", "reInvent2019_wide_ccw", "reInvent2019_wide_cw",
             "reInvent2019_wide_mirrored", "Straight_track"},
        ),
        ("f-min_width=1.4&f-max_width=1.45", {"Austin", "Monaco", "Monaco_building",
                                              "Singapore", "Singapore_building", "Singapore_f1"}),
    ],
)  # fmt: skip
def test_the_tracks_page_searches_and_filters(client, tracks_dir, query, expected) -> None:
    page = client.get(f"/tracks/?{query}").content.decode()
    assert set(card_ids(page)) == expected
    assert f"Showing {len(expected)} of {TOTAL} tracks." in page
    assert f"{TOTAL} tracks available" in page


def test_the_filters_agree_with_the_manifest(client, tracks_dir) -> None:
    page = client.get("/tracks/?f-season=2021&f-source=deepracer").content.decode()
    wanted = {i for i, e in deepracer_manifest().items() if e["season"] == "2021"}
    assert set(card_ids(page)) == wanted and len(wanted) == 16
    page = client.get("/tracks/?f-season=other&f-source=deepracer").content.decode()
    assert set(card_ids(page)) == {i for i, e in deepracer_manifest().items() if not e["season"]}


def test_a_filter_matching_nothing_says_so_and_a_bad_one_filters_nothing(
    client, tracks_dir
) -> None:
    page = client.get("/tracks/?f-q=no+such+track").content.decode()
    assert card_ids(page) == [] and "No track matches these filters." in page
    page = client.get("/tracks/?f-min_length=long").content.decode()
    assert len(card_ids(page)) == TOTAL and "Enter a number." in page


def test_the_race_layout_form_is_not_read_as_a_filter(client, tracks_dir) -> None:
    page = client.get("/tracks/?track=racecraft_oval&direction=cw&race_type=TIME_TRIAL")
    assert len(card_ids(page.content.decode())) == TOTAL


def test_the_wizard_pickers_carry_every_track_and_its_filter_data(alice_client) -> None:
    page = alice_client.get("/models/new/").content.decode()
    radios = re.findall(r'name="track_id" value="([^"]+)"', page)
    extras = re.findall(r'name="extra_track_ids" value="([^"]+)"', page)
    assert len(radios) == len(extras) == TOTAL and "reinvent_base" in radios
    assert radios[:3] == ["racecraft_oval", "racecraft_summit", "racecraft_technical"]
    option = (
        '<label class="option track-option" data-track="re:invent 2018 reinvent_base" '
        'data-season="2018" data-direction="ccw" data-source="deepracer" data-length="17.71" '
        'data-width="0.761">'
    )
    assert option in page, "the re:Invent 2018 option and its filter data"
    # the filter bar is the script's to show: hidden without it, its controls in no form
    assert re.search(r'class="track-filter picker-filter" data-track-filter="\.track-pick-list" '
                     r"hidden>", page)  # fmt: skip
    assert 'form="track-filter-only"' in page and 'id="track-filter-only"' not in page
    assert "js/track_filter.js" in page


@pytest.mark.slow
def test_a_model_on_reinvent_2018_from_the_wizard_with_the_racing_preset_trains(
    alice, alice_client, store_dir, tracks_dir
) -> None:
    """No import: the track is built in, and the training run drives it."""
    source = example_source(RACING.reward_example)
    rewards.reward_validation_remember(
        user_id=alice.pk, source=source, track_id="reinvent_base", direction="native"
    )  # validated on a worker first (tests/console/test_reward_saving.py goes that way)
    page = alice_client.get("/models/new/?start_from=racing").content.decode()
    steering = re.findall(r'name="action_steering" value="([^"]+)"', page)
    speeds = re.findall(r'name="action_speed" value="([^"]+)"', page)
    rows = list(zip(steering, speeds, strict=True))
    hp = RACING.hyperparameters
    data = create_data(
        name="reinvent-racer",
        track_id="reinvent_base",
        action_steering=[s for s, _ in rows],
        action_speed=[v for _, v in rows],
        batch_size=str(hp.batch_size),
        num_epochs=str(hp.num_epochs),
        lr=str(hp.lr),
        beta_entropy=str(hp.beta_entropy),
        discount_factor=str(hp.discount_factor),
        loss_type=hp.loss_type,
        num_episodes_between_training=str(hp.num_episodes_between_training),
        reward_function=source,
        neural_network=re.search(r'<option value="(\w+)" selected>[^<]*CNN', page).group(1),
        start_from=RACING.id,
    )
    response = alice_client.post("/models/new/", data)
    assert response.status_code == 302, response.content.decode()[:2000]
    model = RacingModel.objects.get(name="reinvent-racer")
    assert model.track_id == "reinvent_base" and not TrackFile.objects.exists()
    assert len(model.action_space) == len(RACING.actions())
    model_page = alice_client.get(f"/models/{model.pk}/").content.decode()
    assert "re:Invent 2018" in model_page
    spec = env_spec(model)
    assert spec.track == "reinvent_base" and spec.track_hashes == ()
    _one_training_iteration(model, spec)


class _OneIteration(TrainingHooks):
    def __init__(self) -> None:
        self.results = []

    def on_iteration(self, result, checkpoint, rows) -> None:
        self.results.append(result)

    def should_stop(self) -> bool:
        return bool(self.results)


def _one_training_iteration(model: RacingModel, spec) -> None:
    """One iteration of the model's own training (a few episodes), the worker's way."""
    hooks = _OneIteration()
    config = TrainingConfig(
        spec=spec,
        algorithm=model.algorithm,
        network=model.neural_network,
        hyperparameters=parse_hyperparameters(
            {**model.hyperparameters, "num_episodes_between_training": 2, "num_epochs": 3},
            model.algorithm,
        ),
        max_minutes=60,  # the hooks stop it after one iteration, however loaded the machine
        reward_source=model.reward_function,
        num_envs=2,
        eval_episodes=1,
    )
    summary = train(config, hooks)
    assert summary.iterations == 1 and hooks.results[0].steps > 0
