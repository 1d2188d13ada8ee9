"""Live speed control on race day (leaderboard/speed.py, speedviews.py; training's
race_control): the racer on track sets their car's multiplier; refused when the event has it
off, outside the racer's turn, for anyone else, and for bad values; what the race worker reads;
whose the keys are (an install's own, and forgotten between tests, whose race ids repeat).
Ada races the turn on track, Bo waits for his; Charlie is a spectator. Fran runs the day."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import redis
from django.urls import reverse
from league_helpers import make_event, make_model, make_user

from leaderboard import bracket, raceday, speed
from leaderboard.models import Notification, RaceDaySlot, Submission
from tests.conftest import PER_ROW_KEYS, forget_per_row_keys
from training.models import JobStatus, RaceJob
from training.services import race_control

pytestmark = pytest.mark.django_db


ROOT = Path(__file__).resolve().parents[2]
NOT_STARTED = b"Your car has not started yet: set your speed now or once it drives."


@pytest.fixture(autouse=True)
def _no_speeds_between_tests(settings):
    """Race ids come round again in the next test's database: forget their speed keys (as
    tests/conftest.py now does after every test of every module; kept for the modules that
    import it)."""
    yield
    client = redis.Redis.from_url(settings.REDIS_URL)
    keys = list(client.scan_iter(match=f"{settings.REDIS_PREFIX}racecraft:race-speed:*"))
    if keys:
        client.delete(*keys)
    client.close()


def entry(event, name: str) -> Submission:
    racer = make_user(name, alias=name.title())
    model = make_model(racer, name=f"{name}-car")
    return Submission.objects.create(
        event=event, racer=racer, model=model, model_name=model.name,
        status=Submission.Status.RANKED, entered_model_id=model.pk,
        frozen_checkpoint=f"league/event-{event.pk}/{name}.zip",
        model_metadata={"action_space": model.action_space, "sensor": ["FRONT_FACING_CAMERA"]},
    )  # fmt: skip


@pytest.fixture
def day(fran):
    """A race day with live speed control: Ada's solo run on track, Bo's turn waiting."""
    event = make_event(fran, live_speed_control=True)
    ada, bo = entry(event, "ada"), entry(event, "bo")
    for sub in (ada, bo):
        raceday.race_day_add(event=event, user=fran, submission=sub)
    slot = raceday.race_day_launch(event=event, user=fran)
    return event, ada, bo, slot.race


def post(client, user, event, value, *, json: bool = True):
    client.force_login(user)
    headers = {"HTTP_ACCEPT": "application/json"} if json else {}
    return client.post(reverse("league-race-speed", args=[event.pk]), {"speed": value}, **headers)


def test_the_racer_on_track_sets_their_speed_and_the_race_reads_it(client, day):
    event, ada, _, race = day
    client.force_login(ada.racer)
    page = client.get(reverse("league-race-speed", args=[event.pk]))
    assert page.status_code == 200
    assert b'data-testid="speed-value">1.00<' in page.content  # not changed yet
    assert b"Your car has not started yet" in page.content
    answer = post(client, ada.racer, event, "1.35")
    assert answer.status_code == 200 and answer.json() == {"speed": 1.35}
    assert race_control.race_speeds(race.pk, 1) == [1.35]
    # Without the page's script: the form posts and the page shows the new value.
    page = post(client, ada.racer, event, "0.5", json=False)
    assert page.status_code == 200 and b'data-testid="speed-value">0.50<' in page.content
    assert b'value="0.60"' in page.content  # +0.1 from the value now set
    assert race_control.race_speed_of(race.pk, 0) == 0.5


def test_refused_outside_ones_turn_for_others_and_when_off(client, day, charlie, fran):
    event, ada, bo, race = day
    for user in (bo.racer, charlie, fran):  # Bo waits for his turn; the others have no car
        answer = post(client, user, event, "1.2")
        assert answer.status_code == 403
        assert answer.json()["error"] == (
            "It is not your turn: only the racer on track changes their speed."
        )
        page = client.get(reverse("league-race-speed", args=[event.pk]))
        assert page.status_code == 403 and b"It is not your turn" in page.content
    assert race_control.race_speeds(race.pk, 1) == [None]  # nothing was written
    # The race ends: Ada's turn is over too.
    RaceJob.objects.filter(pk=race.pk).update(status=JobStatus.COMPLETED, results={"cars": []})
    raceday.race_day_race_finished(race_id=race.pk)
    answer = post(client, ada.racer, event, "1.2")
    assert answer.status_code == 403 and "only during your turn" in answer.json()["error"]
    # Off for the event: refused even in one's turn.
    off = make_event(fran, name="No speed")
    cy = entry(off, "cy")
    raceday.race_day_add(event=off, user=fran, submission=cy)
    raceday.race_day_launch(event=off, user=fran)
    answer = post(client, cy.racer, off, "1.2")
    assert answer.status_code == 403
    assert answer.json()["error"] == "Live speed control is off for this event."


@pytest.mark.parametrize(
    ("value", "says"),
    [
        ("1.6", "between 0.5× and 1.5×"),
        ("0.45", "between 0.5× and 1.5×"),
        ("1.03", "in steps of 0.05"),
        ("fast", "must be a number"),
        ("nan", "between 0.5× and 1.5×"),
        ("", "must be a number"),
    ],
)
def test_a_bad_value_is_refused_with_a_sentence_and_changes_nothing(client, day, value, says):
    event, ada, _, race = day
    post(client, ada.racer, event, "1.1")
    answer = post(client, ada.racer, event, value)
    assert answer.status_code == 400 and says in answer.json()["error"]
    assert race_control.race_speed_of(race.pk, 0) == 1.1
    page = post(client, ada.racer, event, value, json=False)
    assert page.status_code == 400 and says.encode() in page.content


def test_in_a_bracket_match_each_racer_sets_only_their_own_car(client, fran):
    event = make_event(fran, live_speed_control=True, bracket_size=4, bracket_on_race_day=True)
    ada, bo = entry(event, "ada"), entry(event, "bo")
    Submission.objects.filter(pk=ada.pk).update(ranked=True, score_ms=30_000)
    Submission.objects.filter(pk=bo.pk).update(ranked=True, score_ms=31_000)
    bracket.bracket_seed(event=event, user=fran)
    race = raceday.race_day_launch(event=event, user=fran).race
    assert [e["tag"] for e in race.entries] == [ada.pk, bo.pk]
    assert post(client, bo.racer, event, "0.7").json() == {"speed": 0.7}
    assert post(client, ada.racer, event, "1.45").json() == {"speed": 1.45}
    assert race_control.race_speeds(race.pk, 2) == [1.45, 0.7]


def test_the_up_next_notice_opens_the_speed_page_when_the_event_has_it(day):
    event, _, bo, _ = day
    note = Notification.objects.get(user=bo.racer, message__contains="up next")
    assert note.link == reverse("league-race-speed", args=[event.pk])
    assert "set your speed" in note.message


def test_the_worker_reads_the_speeds_at_most_every_fifth_of_a_second_of_race_clock(day):
    event, ada, _, race = day
    speeds = race_control.RaceSpeeds(race.pk, 1)
    speed_of = speeds.reader(0)
    assert race_control.race_speed_applied(race.pk, 0) is None  # not driving yet
    assert speed_of(1 / 15) == 1.0  # nothing set: 1.0
    assert race_control.race_speed_applied(race.pk, 0) == 1.0  # driving: reported once
    race_control.race_speed_set(race=race, index=0, multiplier="1.25")
    assert speed_of(2 / 15) == 1.0  # read 1/15 s ago: the copy stands
    assert speed_of(4 / 15) == 1.25  # 0.2 s on: read again
    assert race_control.race_speed_applied(race.pk, 0) == 1.25
    assert speeds.log == [[1.0, 1.0, 1.25]]  # one value per step, for the trace


def test_stopping_the_race_on_track_goes_through_trainings_service(day, fran):
    event, _, _, race = day
    RaceJob.objects.filter(pk=race.pk).update(status=JobStatus.IN_PROGRESS)  # a worker drives it
    raceday.race_day_stop(event=event, user=fran)
    assert RaceJob.objects.get(pk=race.pk).stop_requested
    assert RaceJob.objects.get(pk=race.pk).status == JobStatus.IN_PROGRESS  # stops at its next step
    assert RaceDaySlot.objects.get(race=race).status == RaceDaySlot.Status.RUNNING
    RaceJob.objects.filter(pk=race.pk).update(status=JobStatus.CANCELED)
    assert race_control.race_stop(race=race, by="test") is False  # already over
    ada = Submission.objects.get(event=event, model_name="ada-car").racer
    with pytest.raises(speed.LeagueError, match="this race is over"):
        speed.race_speed_change(event=event, user=ada, multiplier="1.0")


def test_stopping_a_race_still_queued_cancels_it_and_ends_the_turn_at_once(
    day, fran, django_capture_on_commit_callbacks
):
    """No worker has claimed the race yet: it never starts, and the next turn can launch now."""
    event, _, bo, race = day
    assert RaceJob.objects.get(pk=race.pk).status == JobStatus.QUEUED
    with django_capture_on_commit_callbacks(execute=True):
        raceday.race_day_stop(event=event, user=fran)
    assert RaceJob.objects.get(pk=race.pk).status == JobStatus.CANCELED
    assert RaceDaySlot.objects.get(race=race).status == RaceDaySlot.Status.DONE
    assert raceday.race_day_launch(event=event, user=fran).submission == bo


def page_says(client, user, event) -> tuple[bytes, bytes]:
    """The speed page's value and what it says the car drives at."""
    client.force_login(user)
    page = client.get(reverse("league-race-speed", args=[event.pk]))
    assert page.status_code == 200
    value = re.search(rb'data-testid="speed-value">([^<]*)<', page.content)
    driving = re.search(rb'data-testid="speed-driving"[^>]*>([^<]*)<', page.content)
    assert value and driving, page.content
    return value.group(1), driving.group(1)


def test_another_install_s_race_of_the_same_id_is_not_this_one(client, day, settings):
    """Two installs, or two test processes, on one Redis each number their races from 1: the
    keys of one's race 1 are not the other's (REDIS_PREFIX, drawn per xdist worker in the
    tests)."""
    event, ada, _, race = day
    ours = settings.REDIS_PREFIX
    race_control.race_speed_set(race=race, index=0, multiplier="1.3")
    race_control.RaceSpeeds(race.pk, 1).value(0, 0.0)  # our race drives at it
    settings.REDIS_PREFIX = theirs = f"{ours}other-install:"
    try:
        assert race_control.race_speeds(race.pk, 1) == [None]
        assert race_control.race_speed_applied(race.pk, 0) is None
        assert page_says(client, ada.racer, event) == (b"1.00", NOT_STARTED)
        race_control.race_speed_set(race=race, index=0, multiplier="0.7")  # their race 1
        race_control.RaceSpeeds(race.pk, 1).value(0, 0.0)
    finally:
        settings.REDIS_PREFIX = ours
        shared = redis.Redis.from_url(settings.REDIS_URL)
        left = list(shared.scan_iter(match=f"{theirs}*"))
        if left:
            shared.delete(*left)
        shared.close()
    assert race_control.race_speed_of(race.pk, 0) == 1.3
    assert page_says(client, ada.racer, event) == (b"1.30", "On track now at 1.30×.".encode())


def test_what_an_earlier_race_of_the_same_id_left_is_forgotten_before_the_next_test(client, day):
    """On SQLite a test's rolled-back rows give their ids back: the next test's first race is
    race 1 again. Keys a finished race left under its id (what its car drove at, kept an
    hour) would show on the next race 1's page; tests/conftest.py forgets them after each
    test (:func:`forget_per_row_keys`, run here by hand)."""
    event, ada, _, race = day
    race_control.RaceSpeeds(race.pk, 1).value(0, 0.0)  # a race with this id drove at 1.0
    assert page_says(client, ada.racer, event) == (b"1.00", "On track now at 1.00×.".encode())
    forget_per_row_keys()
    assert page_says(client, ada.racer, event) == (b"1.00", NOT_STARTED)


def test_every_family_of_keys_named_after_rows_is_forgotten_between_tests():
    """Every ``racecraft:<family>:`` key the code builds is either forgotten after each test
    (tests/conftest.py's PER_ROW_KEYS: named after user, job or race ids, which repeat from
    test to test on SQLite) or named so it cannot repeat: a new family named after rows must
    join PER_ROW_KEYS."""
    random_or_not_a_key = {"sim", "broadcast"}  # sim:<uuid>; broadcast: a pub/sub channel
    found = set()
    for package in ("console", "leaderboard", "racing", "training"):
        for path in (ROOT / package).rglob("*.py"):
            found |= set(re.findall(r"\bracecraft:([a-z][a-z-]*):", path.read_text()))
    assert {"race-speed", "watching", "sim"} <= found  # the search finds them
    assert found - random_or_not_a_key == set(PER_ROW_KEYS)
