"""The live speed page follows the race day by itself (Chromium through Playwright against
daphne on the test database and Redis): Bo opens it while Ada is on track and is told it is
not his turn; Ada's race ends and Fran launches Bo's turn: without a reload Bo's page gets the
buttons, then says what his car drives at once it drives; his turn ends and the page says so.
No worker: the test moves the race day itself, as the worker and the facilitator would."""

from __future__ import annotations

import pytest
from league_helpers import make_event
from test_race_day_browser import page_of
from test_speed import _no_speeds_between_tests, entry  # noqa: F401 - a fixture

from leaderboard import raceday
from training import dispatch
from training.models import JobStatus, RaceJob
from training.services import race_control

pytestmark = [pytest.mark.browser, pytest.mark.slow, pytest.mark.django_db(transaction=True),
              pytest.mark.timeout(300)]  # fmt: skip


def end_turn(race: RaceJob) -> None:
    RaceJob.objects.filter(pk=race.pk).update(status=JobStatus.COMPLETED, results={"cars": []})
    raceday.race_day_race_finished(race_id=race.pk)


def test_the_speed_page_follows_whose_turn_it_is_without_a_reload(
    browser, daphne, fran, monkeypatch
):
    monkeypatch.setattr(dispatch, "send", lambda name, pk: "")  # no worker runs these races
    event = make_event(fran, live_speed_control=True)
    ada, bo = entry(event, "ada"), entry(event, "bo")
    for sub in (ada, bo):
        raceday.race_day_add(event=event, user=fran, submission=sub)
    ada_race = raceday.race_day_launch(event=event, user=fran).race

    phone = page_of(browser, daphne.url, bo.racer, width=375, height=740)
    errors: list[str] = []
    phone.on("pageerror", lambda e: errors.append(str(e)))
    answer = phone.goto(f"{daphne.url}/league/events/{event.pk}/speed/")
    assert answer.status == 403
    assert "not your turn" in phone.inner_text("[data-testid=speed-error]")
    assert phone.locator("[data-testid=speed-value]").count() == 0

    end_turn(ada_race)
    bo_race = raceday.race_day_launch(event=event, user=fran).race
    phone.wait_for_selector("[data-testid=speed-value]:text-is('1.00')")  # his turn: the buttons
    assert "has not started yet" in phone.inner_text("[data-testid=speed-driving]")
    race_control.race_speed_set(race=bo_race, index=0, multiplier="1.2")
    race_control.RaceSpeeds(bo_race.pk, 1).value(0, 0.0)  # the worker drives at it
    phone.wait_for_selector("[data-testid=speed-driving][data-driving='1.20']")
    assert phone.inner_text("[data-testid=speed-driving]") == "On track now at 1.20×."
    assert phone.inner_text("[data-testid=speed-value]") == "1.20"

    end_turn(bo_race)
    phone.wait_for_selector("[data-testid=speed-error]:has-text('only during your turn')")
    assert phone.locator("[data-testid=speed-value]").count() == 0
    assert errors == []
