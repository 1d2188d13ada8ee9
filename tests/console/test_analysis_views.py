"""The analysis pages: the owner's charts as JSON and CSV, 404 for anyone else, and reward
replays (queued as a task; the task's body run here directly)."""

from __future__ import annotations

import pytest

from racing.tracks import TrackCatalog
from tests.console.conftest import make_model
from training.analysis.synthetic import synthetic_iteration
from training.models import RacingModel
from training.services import analysis
from training.store import get_store, keys_for

pytestmark = pytest.mark.django_db


@pytest.fixture
def logged_model(alice_model: RacingModel) -> RacingModel:
    """Alice's model with three iterations of (synthetic) training logs in the store."""
    track = TrackCatalog([]).load(alice_model.track_id)
    store, keys = get_store(), keys_for(alice_model.pk)
    for it in range(3):
        data = synthetic_iteration(track, iteration=it, episodes=8, num_actions=3, mean_steps=30)
        store.put_bytes(keys.simtrace(it), data, "text/csv")
    return alice_model


def test_the_owner_sees_the_analysis(alice_client, logged_model) -> None:
    page = alice_client.get(f"/models/{logged_model.pk}/analysis/")
    assert page.status_code == 200 and b"track-canvas" in page.content
    detail = alice_client.get(f"/models/{logged_model.pk}/")
    assert f"/models/{logged_model.pk}/analysis/".encode() in detail.content
    base = f"/models/{logged_model.pk}/analysis/data/"
    progress = alice_client.get(base + "progress.json").json()
    assert progress["iteration"] == [0, 1, 2] and progress["episodes"] == [8, 8, 8]
    for kind in ("reward", "speed", "action"):
        heat = alice_client.get(base + f"heatmap.json?kind={kind}").json()
        assert heat["kind"] == kind and heat["steps"] > 0
    assert alice_client.get(base + "heatmap.json?kind=nope").status_code == 400
    actions = alice_client.get(base + "actions.json").json()
    assert len(actions["actions"]) == 3 and len(actions["per_iteration"]) == 3
    episodes = alice_client.get(base + "episodes.json").json()
    assert len(episodes["episode"]) == 24
    it, ep = episodes["iteration"][9], episodes["episode"][9]
    path = alice_client.get(f"/models/{logged_model.pk}/analysis/episode/{it}/{ep}/").json()
    assert len(path["x"]) == episodes["steps"][9]
    csv = alice_client.get(base + "fastest.csv")
    assert csv["Content-Type"] == "text/csv" and csv.content.startswith(b"iteration,episode")
    heat_csv = alice_client.get(base + "heatmap.csv?kind=speed").content.decode().splitlines()
    assert heat_csv[0] == "x,y,speed" and len(heat_csv) > 10
    assert alice_client.get(base + "evaluations.json").json() == {"evaluations": []}
    assert alice_client.get(base + "nope.json").status_code == 400


def test_a_model_without_logs_has_empty_charts(alice_client, alice_model) -> None:
    data = alice_client.get(f"/models/{alice_model.pk}/analysis/data/progress.json").json()
    assert data["iteration"] == []


def test_someone_elses_analysis_is_a_404(charlie_client, logged_model) -> None:
    urls = ["", "data/progress.json", "data/heatmap.csv", "episode/0/0/", "replay/abc/"]
    for url in urls:
        response = charlie_client.get(f"/models/{logged_model.pk}/analysis/{url}")
        assert response.status_code == 404, url
    replay = charlie_client.post(f"/models/{logged_model.pk}/analysis/replay/", "{}",
                                 content_type="application/json")  # fmt: skip
    assert replay.status_code == 404


def test_replay_refuses_bad_code_and_reruns_a_recorded_episode(alice_client, logged_model) -> None:
    url = f"/models/{logged_model.pk}/analysis/replay/"
    bad = alice_client.post(url, {"iteration": 0, "episode": 0, "reward_function": "import os"},
                            content_type="application/json")  # fmt: skip
    assert bad.status_code == 400 and "error" in bad.json()
    missing = alice_client.post(url, {"iteration": 7, "episode": 0,
                                      "reward_function": "def reward_function(p):\n  return 1.0"},
                                content_type="application/json")  # fmt: skip
    assert missing.status_code == 400
    source = "def reward_function(params):\n    return 2.0 * params['speed']\n"
    result = analysis.replay_run(logged_model.pk, 1, 9, source)
    assert result["model"] == logged_model.pk and not result["errors"]
    assert len(result["new_reward"]) == len(result["old_reward"]) > 0
    speeds = analysis.analysis_episode(logged_model, 1, 9)["speed"]
    assert result["new_reward"] == pytest.approx([2 * s for s in speeds], abs=1e-3)


def test_a_continuous_model_has_action_charts(alice, alice_client, store_dir) -> None:
    space = {"steering_angle": {"low": -30.0, "high": 30.0}, "speed": {"low": 1.0, "high": 2.5}}
    model = make_model(alice, name="alice-continuous", action_space=space)
    track = TrackCatalog([]).load(model.track_id)
    store, keys = get_store(), keys_for(model.pk)
    for it in range(2):
        data = synthetic_iteration(track, iteration=it, episodes=6, num_actions=0, mean_steps=30,
                                   continuous=((-30.0, 30.0), (1.0, 2.5)))  # fmt: skip
        store.put_bytes(keys.simtrace(it), data, "text/csv")
    base = f"/models/{model.pk}/analysis/data/"
    heat = alice_client.get(base + "heatmap.json?kind=action").json()
    assert len(heat["actions"]) == 15 and {v for v in heat["values"] if v is not None}
    actions = alice_client.get(base + "actions.json").json()
    assert actions["continuous"] and len(actions["actions"]) == 15
    assert [len(row) for row in actions["per_iteration"]] == [15, 15]
    assert store.exists(keys.prefix + analysis.SUMMARY_NAME)  # made on the first view, kept
    csv = alice_client.get(base + "actions.csv").content.decode().splitlines()
    assert csv[0].startswith("iteration,-30..-18° 1.00..1.50 m/s,") and len(csv) == 3
