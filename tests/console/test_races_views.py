"""The Races pages (console/views/races.py) and the race's websocket: Alice races her car
against Bob's open one; Bob sees who raced it (the result and the replay, not Alice's traces);
Charlie sees nothing (404, and 4404 on the socket). Bad input is answered on the form, which
keeps what was typed; only a model's owner opens it to challenges."""

from __future__ import annotations

import re

import pytest
from asgiref.sync import async_to_sync
from django.test import Client

from tests.console.conftest import make_model
from tests.console.test_consumers import connect
from training.models import JobStatus, RaceJob, RacingModel
from training.store import get_store, keys_for

pytestmark = pytest.mark.django_db


def trained(owner, name: str, **flags) -> RacingModel:
    """A model with a stored "best checkpoint" (bytes enough to be frozen; never raced here)."""
    model = make_model(owner, name)
    get_store().put_bytes(keys_for(model.pk).best, b"weights")
    RacingModel.objects.filter(pk=model.pk).update(has_checkpoint=True, **flags)
    return RacingModel.objects.get(pk=model.pk)


def logged_in(user) -> Client:
    client = Client()
    client.force_login(user)
    return client


@pytest.fixture
def field(alice, bob, store_dir):
    """Alice's car, Bob's open car and his closed one."""
    return (trained(alice, "alice-car"), trained(bob, "bob-open", open_to_challenges=True),
            trained(bob, "bob-closed"))  # fmt: skip


def form(model: RacingModel, *opponents: RacingModel, **extra) -> dict:
    return {"model": model.pk, "opponents": [o.pk for o in opponents],
            "track_id": "racecraft_oval", "direction": "native", "laps": 2, "bots": 0,
            **extra}  # fmt: skip


def test_a_racer_starts_a_race_against_an_open_model_and_each_sees_their_part(
    field, alice, bob, charlie
):
    alice_car, bob_open, bob_closed = field
    a, b, c = logged_in(alice), logged_in(bob), logged_in(charlie)
    page = a.get("/races/new/").content.decode()
    assert "bob-open (bob)" in page and "bob-closed" not in page

    response = a.post("/races/new/", form(alice_car, bob_open))
    race = RaceJob.objects.get()
    assert response.status_code == 302 and response.url == f"/races/{race.pk}/"
    watch = a.get(f"/races/{race.pk}/").content.decode()  # queued: the broadcast view
    # the race-day broadcast's stage and script, on the race's own socket
    assert f'data-socket-url="/ws/races/{race.pk}/"' in watch
    assert "leaderboard/broadcast.js" in watch and "race_watch.js" not in watch
    assert "data-tower" in watch and "data-pip-labels" in watch and "data-winner" in watch
    assert "alice-car v bob-open" in a.get("/races/").content.decode()

    RaceJob.objects.filter(pk=race.pk).update(
        status=JobStatus.COMPLETED, has_video=True,
        results={"winner": bob_open.pk, "cars": [
            {"model": bob_open.pk, "name": "bob-open", "position": 1, "laps": 2,
             "finished": True, "total_time_s": 20.5, "status": "finished", "reason": "",
             "off_track": 0, "crashes": 0},
            {"model": alice_car.pk, "name": "alice-car", "position": 2, "laps": 1,
             "finished": False, "total_time_s": None, "status": "time_up", "reason": "",
             "off_track": 3, "crashes": 1}]},
    )  # fmt: skip
    get_store().put_bytes(f"races/{race.pk}/broadcast.mp4", b"\0\0\0\x18ftypmp42")
    get_store().put_bytes(f"races/{race.pk}/{alice_car.pk}/model/model_metadata.json", b"{}")
    mine = a.get(f"/races/{race.pk}/").content.decode()
    assert 'id="race-traces"' in mine and 'id="race-replay"' in mine
    assert a.get(f"/races/{race.pk}/traces.tar.gz").status_code == 200

    theirs = b.get("/races/").content.decode()
    assert 'data-challenger="alice"' in theirs and "P1 of 2" in theirs
    bobs = b.get(f"/races/{race.pk}/").content.decode()
    assert "alice raced your model" in bobs and 'id="race-traces"' not in bobs
    assert b.get(f"/races/{race.pk}/video.mp4").status_code == 200
    assert b.get(f"/races/{race.pk}/traces.tar.gz").status_code == 404

    for path in ("", "video.mp4", "traces.tar.gz"):
        assert c.get(f"/races/{race.pk}/{path}").status_code == 404
    assert "alice-car" not in c.get("/races/").content.decode()


def test_bad_input_is_answered_on_the_form_which_keeps_what_was_typed(field, alice, settings):
    alice_car, bob_open, bob_closed = field
    a = logged_in(alice)
    response = a.post("/races/new/", form(alice_car, bob_open, laps=9, direction="cw"))
    page = response.content.decode()
    assert response.status_code == 400 and "less than or equal to 5" in page
    assert 'value="cw" selected' in page
    assert re.search(rf'value="{bob_open.pk}"[^>]*checked', page)
    response = a.post("/races/new/", form(alice_car, bob_closed))  # not offered: not open
    assert response.status_code == 400 and "Select a valid choice" in response.content.decode()
    response = a.post("/races/new/", form(alice_car, bob_open, track_id="nowhere", bots=7))
    page = response.content.decode()
    assert response.status_code == 400 and "Select a valid choice. nowhere" in page
    assert "less than or equal to 6" in page
    assert not RaceJob.objects.exists()
    # A refusal of the service (here the quota) is shown on the form, which keeps its values.
    settings.RACECRAFT_MAX_ACTIVE_JOBS_PER_USER = 1
    assert a.post("/races/new/", form(alice_car, bob_open)).status_code == 302
    response = a.post("/races/new/", form(alice_car, bob_open, laps=4))
    page = response.content.decode()
    assert response.status_code == 400 and "1 jobs queued or running" in page
    assert 'name="laps" value="4"' in page and RaceJob.objects.count() == 1


def test_only_the_owner_opens_a_model_to_challenges(field, alice, charlie):
    alice_car = field[0]
    page = logged_in(alice).get(f"/models/{alice_car.pk}/").content.decode()
    assert 'id="open-challenges"' in page and "frozen copy" in page
    assert logged_in(charlie).post(f"/models/{alice_car.pk}/challenges/",
                                   {"open": "1"}).status_code == 404  # fmt: skip
    assert not RacingModel.objects.get(pk=alice_car.pk).open_to_challenges
    logged_in(alice).post(f"/models/{alice_car.pk}/challenges/", {"open": "1"})
    assert RacingModel.objects.get(pk=alice_car.pk).open_to_challenges
    logged_in(alice).post(f"/models/{alice_car.pk}/challenges/", {"open": "0"})
    assert not RacingModel.objects.get(pk=alice_car.pk).open_to_challenges


@pytest.mark.django_db(transaction=True)
def test_only_the_challenger_watches_the_race_live(field, alice, bob, charlie):
    alice_car, bob_open, _ = field
    logged_in(alice).post("/races/new/", form(alice_car, bob_open))
    race = RaceJob.objects.get()
    clients = {name: logged_in(user) for name, user in (("a", alice), ("b", bob),
                                                        ("c", charlie))}  # fmt: skip

    async def scenario() -> None:
        ws, connected, _ = await connect(clients["a"], f"/ws/races/{race.pk}/")
        assert connected
        status = await ws.receive_json_from(timeout=10)
        assert status == {"type": "status", "status": "QUEUED"}
        await ws.disconnect()
        for name in ("b", "c"):
            ws, connected, code = await connect(clients[name], f"/ws/races/{race.pk}/")
            assert not connected and code == 4404

    async_to_sync(scenario)()


def test_the_race_status_reads_as_the_broadcast_s_status_message():
    from console.race_watch import race_status

    assert race_status("IN_PROGRESS", None) == {"type": "status", "status": "IN_PROGRESS",
                                                "started": True}  # fmt: skip
    results = {"winner": 7, "stopped": False, "cars": [
        {"model": 9, "name": "slow", "total_time_s": 30.0},
        {"model": 7, "name": "fast", "total_time_s": 21.5}]}  # fmt: skip
    assert race_status("COMPLETED", results) == {
        "type": "status", "status": "COMPLETED", "over": True, "outcome": "Finished",
        "winner": "fast", "winner_time_s": 21.5}  # fmt: skip
    stopped = race_status("COMPLETED", {**results, "winner": None, "stopped": True})
    assert stopped["outcome"] == "Stopped" and stopped["winner"] is None
    assert race_status("FAILED", None)["outcome"] == "Failed"


def test_only_the_challenger_stops_their_race(field, alice, bob, charlie):
    alice_car, bob_open, _ = field
    logged_in(alice).post("/races/new/", form(alice_car, bob_open))
    race = RaceJob.objects.get()
    assert 'id="stop-race"' in logged_in(alice).get(f"/races/{race.pk}/").content.decode()
    assert logged_in(alice).get(f"/races/{race.pk}/stop/").status_code == 405
    for user in (bob, charlie):  # an opponent's owner and a stranger: no such race
        assert logged_in(user).post(f"/races/{race.pk}/stop/").status_code == 404
    assert not RaceJob.objects.get(pk=race.pk).stop_requested
    csrf = Client(enforce_csrf_checks=True)
    csrf.force_login(alice)
    assert csrf.post(f"/races/{race.pk}/stop/").status_code == 403  # no CSRF token
    assert not RaceJob.objects.get(pk=race.pk).stop_requested

    # A worker has it (a queued race is canceled instead: the next test).
    RaceJob.objects.filter(pk=race.pk).update(status=JobStatus.IN_PROGRESS)
    response = logged_in(alice).post(f"/races/{race.pk}/stop/")
    assert response.status_code == 302 and response.url == f"/races/{race.pk}/"
    stopping = RaceJob.objects.get(pk=race.pk)
    assert stopping.stop_requested and stopping.status == JobStatus.IN_PROGRESS
    assert "Stopping…" in logged_in(alice).get(f"/races/{race.pk}/").content.decode()
    RaceJob.objects.filter(pk=race.pk).update(status=JobStatus.COMPLETED)
    response = logged_in(alice).post(f"/races/{race.pk}/stop/", follow=True)
    assert "already ended" in response.content.decode()
