"""The league pages through Django's test client: home, profile, event creation, the
leaderboard, the wide-screen mode, submitting, and who may watch a submission's video."""

from __future__ import annotations

import pytest
from league_helpers import finish_evaluation, lap, make_event, make_model

from leaderboard.models import Event, Submission
from leaderboard.services import submission_create

pytestmark = pytest.mark.django_db


def test_home_for_visitors_and_racers(client, event, alice):
    page = client.get("/league/")
    assert page.status_code == 200 and "Log in to race" in page.content.decode()
    assert "Oval sprint" in page.content.decode()
    client.force_login(alice)
    html = client.get("/league/").content.decode()
    assert 'id="my-division"' in html and "Open division" in html
    assert "New league event" not in html  # racers organise community races only


def test_profile_form_sets_the_alias_once(client, db):
    from league_helpers import make_user

    dave = make_user("dave")
    client.force_login(dave)
    response = client.post("/league/", {"alias": "DaveDrives", "country": "fr",
                                        "colour": "#112233"})  # fmt: skip
    assert response.status_code == 302
    html = client.get("/league/").content.decode()
    assert "Your racer alias is fixed." in html
    client.post("/league/", {"alias": "Changed", "country": "FR", "colour": "#112233"})
    assert dave.racer_profile.alias == "DaveDrives"


def test_facilitators_create_events_through_the_form(client, fran, alice):
    data = {"name": "Spring Open", "description": "", "division": "OPEN",
            "track_id": "racecraft_oval", "direction": "native", "race_type": "TIME_TRIAL",
            "opens_at": "2030-03-01T00:00", "closes_at": "2030-03-31T00:00",
            "ranking_method": "TOTAL_TIME", "min_laps": 3, "max_laps": 3,
            "off_track_penalty_s": 2, "collision_penalty_s": 5, "max_resets": "",
            "max_submissions_per_racer": 10, "number_of_objects": 0, "bot_count": 0,
            "bot_speed_mps": 1.0}  # fmt: skip
    client.force_login(alice)
    assert client.get("/league/events/new/")["Location"] == "/league/community/new/"
    client.force_login(fran)
    assert client.get("/league/events/new/").status_code == 200
    response = client.post("/league/events/new/", {**data, "min_laps": 4})
    assert "minimum ≤ maximum" in response.content.decode()
    response = client.post("/league/events/new/", data)
    event = Event.objects.get(name="Spring Open")
    assert response["Location"] == f"/league/events/{event.pk}/"
    assert (event.ranking_method, event.min_laps, event.is_private) == ("TOTAL_TIME", 3, False)


def test_object_avoidance_events_through_the_form(client, fran):
    """The race rules answer on the form's fields; the event page shows the boxes."""
    data = {"name": "Box Open", "description": "", "division": "PRO",
            "track_id": "racecraft_oval", "direction": "native", "race_type": "OBJECT_AVOIDANCE",
            "opens_at": "2030-03-01T00:00", "closes_at": "2030-03-31T00:00",
            "ranking_method": "TOTAL_TIME", "min_laps": 3, "max_laps": 3,
            "off_track_penalty_s": 5, "collision_penalty_s": 5, "max_resets": "",
            "max_submissions_per_racer": 10, "number_of_objects": 0, "bot_count": 0,
            "bot_speed_mps": 1.0}  # fmt: skip
    client.force_login(fran)
    page = client.post("/league/events/new/", data).content.decode()
    assert "number_of_objects must be an integer from 1 to 6, not 0" in page
    assert "<details open>" in page  # the settings are shown with their error
    response = client.post("/league/events/new/", {**data, "number_of_objects": 4,
                                                   "randomize_objects": "on"})  # fmt: skip
    event = Event.objects.get(name="Box Open")
    assert response["Location"] == f"/league/events/{event.pk}/"
    assert "4, placed at random" in client.get(f"/league/events/{event.pk}/").content.decode()


def test_event_page_submit_and_screen(client, event, alice):
    model = make_model(alice)
    client.force_login(alice)
    html = client.get(f"/league/events/{event.pk}/").content.decode()
    assert "Enter a model" in html and f'value="{model.pk}"' in html
    assert "<dd>Racecraft Oval</dd>" in html  # the track's name, not its id
    response = client.post(f"/league/events/{event.pk}/submit/", {"model": model.pk}, follow=True)
    assert "is submitted" in response.content.decode()
    sub = Submission.objects.get()
    finish_evaluation(sub.evaluation, [lap(10.0)])
    response = client.post(f"/league/events/{event.pk}/submit/", {"model": model.pk}, follow=True)
    assert response.status_code == 200  # the model is ready again: a second submission
    html = client.get(f"/league/events/{event.pk}/").content.decode()
    assert 'data-racer="Alice-R"' in html and "00:10.000" in html
    for url in (f"/league/events/{event.pk}/screen/", f"/league/events/{event.pk}/?screen=1"):
        screen = client.get(url).content.decode()
        assert "lb-screen" in screen and 'class="nav"' not in screen and "00:10.000" in screen


def test_refusals_are_shown_as_messages(client, event, alice, bob):
    client.force_login(bob)
    response = client.post(f"/league/events/{event.pk}/submit/",
                           {"model": make_model(alice).pk}, follow=True)  # fmt: skip
    assert "You can only submit your own models." in response.content.decode()


def test_a_racer_without_an_alias_is_sent_to_the_profile(client, event, settings, tmp_path):
    from django.contrib.auth import get_user_model

    settings.STORE_DIR = tmp_path / "store"
    newcomer = get_user_model().objects.create_user("newcomer", password="x-long-pass-1")
    make_model(newcomer)
    client.force_login(newcomer)
    html = client.get(f"/league/events/{event.pk}/").content.decode()
    assert 'id="needs-alias"' in html and 'href="/league/#profile"' in html


def test_the_promotion_rule_is_on_the_league_pages(client, event, alice):
    client.force_login(alice)
    for url in ("/league/", f"/league/events/{event.pk}/"):
        html = client.get(url).content.decode()
        assert 'id="promotion"' in html
        assert "rounded up" in html and "tied" in html and "10%" in html


def test_submission_figures_say_what_they_cover(client, fran, alice):
    event = make_event(fran, min_laps=1)
    sub = submission_create(event=event, user=alice, model=make_model(alice))
    finish_evaluation(sub.evaluation, [lap(34.4), lap(34.6), lap(34.5)])
    client.force_login(alice)
    html = client.get(f"/league/submissions/{sub.pk}/").content.decode()
    assert "1 consecutive completed lap</strong> (its minimum)" in html
    assert "(so one lap, not all" in html
    assert "Lap complete" in html and "Lapcomplete" not in html


def test_who_may_watch_a_submission(client, event, alice, bob, settings, tmp_path):
    settings.STORE_DIR = tmp_path / "store"
    sub = submission_create(event=event, user=alice, model=make_model(alice))
    detail = f"/league/submissions/{sub.pk}/"
    video = f"/league/submissions/{sub.pk}/video.mp4"
    client.force_login(bob)
    assert client.get(detail).status_code == 404  # not ranked yet: only Alice
    finish_evaluation(sub.evaluation, [lap(10.0)])
    from training.store import get_store, keys_for

    get_store().put_bytes(keys_for(sub.evaluation.model_id).video(sub.evaluation_id), b"mp4",
                          "video/mp4")  # fmt: skip
    type(sub.evaluation).objects.filter(pk=sub.evaluation_id).update(has_video=True)
    assert client.get(detail).status_code == 200
    response = client.get(video)
    assert response.status_code == 200 and response["Content-Type"] == "video/mp4"
    partial = client.get(video, HTTP_RANGE="bytes=1-2")  # browsers seek with ranges
    assert partial.status_code == 206 and partial.content == b"p4"
    assert b"".join(response.streaming_content) == b"mp4"
    client.logout()
    assert client.get(video).status_code == 200  # a public event: anyone may watch


def test_unranked_runs_stay_with_their_racer(client, fran, alice, bob):
    event = make_event(fran, min_laps=3)
    sub = submission_create(event=event, user=alice, model=make_model(alice))
    finish_evaluation(sub.evaluation, [lap(10.0), lap(3.0, "off_track")])
    client.force_login(bob)
    assert client.get(f"/league/submissions/{sub.pk}/").status_code == 404
    client.force_login(alice)
    html = client.get(f"/league/submissions/{sub.pk}/").content.decode()
    assert "Not ranked" in html and "00:10.000" in html
    client.force_login(fran)  # facilitators see every submission
    assert client.get(f"/league/submissions/{sub.pk}/").status_code == 200
    assert "All submissions" in client.get(f"/league/events/{event.pk}/").content.decode()
