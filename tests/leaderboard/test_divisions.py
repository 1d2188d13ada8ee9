"""Month-end promotion: the top 10% of a month's Open time trials move to Pro, ties at the
line included, nobody from an empty month, and running it twice changes nothing."""

from __future__ import annotations

from datetime import UTC, date, datetime, timedelta
from fractions import Fraction

import pytest
from django.core.management import call_command
from league_helpers import make_event, make_user

from leaderboard import divisions
from leaderboard.models import Division, DivisionMembership, Notification, Submission
from leaderboard.tasks import promote_divisions

MARCH = date(2025, 3, 1)
APRIL = date(2025, 4, 1)
IN_MARCH = datetime(2025, 3, 15, 12, tzinfo=UTC)

pytestmark = pytest.mark.django_db


@pytest.fixture
def march_event(fran):
    return make_event(fran, name="March TT", opens_at=datetime(2025, 3, 1, tzinfo=UTC),
                      closes_at=datetime(2025, 4, 1, tzinfo=UTC))  # fmt: skip


def racers(n: int, prefix: str = "r") -> list:
    return [make_user(f"{prefix}{i:02d}") for i in range(n)]


def ranked(event, racer, score_ms: int, when: datetime = IN_MARCH) -> Submission:
    return Submission.objects.create(event=event, racer=racer, model_name="m", score_ms=score_ms,
                                     status=Submission.Status.RANKED, ranked=True,
                                     created_at=when)  # fmt: skip


def pro_next_month(month: date = APRIL) -> set[str]:
    return set(
        DivisionMembership.objects.filter(month=month, division=Division.PRO).values_list(
            "racer__username", flat=True
        )
    )


def test_top_ten_percent_move_up_and_are_told(march_event) -> None:
    field = racers(20)
    for i, racer in enumerate(field):
        ranked(march_event, racer, 10_000 + i * 100)
    result = divisions.divisions_promote(month=MARCH)
    assert result.racers == 20
    assert pro_next_month() == {"r00", "r01"}
    note = Notification.objects.get(user=field[0])
    assert "Pro" in note.message and "March 2025" in note.message
    assert divisions.division_for(field[0], APRIL) == Division.PRO
    assert divisions.division_for(field[0], date(2025, 7, 9)) == Division.PRO  # Pro stays Pro
    assert divisions.division_for(field[0], MARCH) == Division.OPEN
    assert divisions.division_for(field[2], APRIL) == Division.OPEN


def test_the_promoted_racer_sees_the_news_on_their_league_page(march_event, client) -> None:
    (winner,) = racers(1)
    ranked(march_event, winner, 10_000)
    divisions.divisions_promote(month=MARCH)
    client.force_login(winner)
    html = client.get("/league/").content.decode()
    assert 'class="unread"' in html and "Pro division from April 2025" in html
    html = client.get("/league/").content.decode()
    assert 'class="unread"' not in html and "Pro division from April 2025" in html


def test_ties_at_the_line_are_all_promoted(march_event) -> None:
    field = racers(20)
    times = [10_000, 10_500, 10_500, 10_500] + [12_000 + i for i in range(16)]
    for racer, ms in zip(field, times, strict=True):
        ranked(march_event, racer, ms)
    divisions.divisions_promote(month=MARCH)
    # k = 2: the 2nd best standing is shared by three racers, so four move up
    assert pro_next_month() == {"r00", "r01", "r02", "r03"}


def test_a_racer_counts_once_with_their_best_standing_across_events(fran, march_event) -> None:
    other = make_event(fran, name="March TT 2", opens_at=datetime(2025, 3, 1, tzinfo=UTC),
                       closes_at=datetime(2025, 4, 1, tzinfo=UTC))  # fmt: skip
    field = racers(11)
    for i, racer in enumerate(field):
        ranked(march_event, racer, 10_000 + i * 100)  # r00 wins, r05 is sixth
    order = [field[5], field[0], *field[1:5], *field[6:]]
    for i, racer in enumerate(order):
        ranked(other, racer, 30_000 + i * 100)  # r05 wins, r00 is second
    ranked(other, field[5], 40_000, when=IN_MARCH + timedelta(hours=1))  # a worse retry
    standings = divisions.monthly_standings(MARCH)
    assert len(standings) == 11
    assert standings[field[0].pk] == standings[field[5].pk] == Fraction(1, 11)
    assert standings[field[1].pk] == Fraction(2, 11)
    divisions.divisions_promote(month=MARCH)
    # two slots (ceil(11 / 10)); both winners share the best standing
    assert pro_next_month() == {"r00", "r05"}


def test_only_open_public_time_trials_of_that_month_count(fran) -> None:
    pro = make_event(fran, name="Pro race", division=Division.PRO)
    private = make_event(fran, name="Friends", is_private=True)
    oa = make_event(fran, name="Boxes", race_type="OBJECT_AVOIDANCE")
    march = make_event(fran, name="TT")
    a, b, c, d = racers(4)
    ranked(pro, a, 1000)
    ranked(private, b, 1000)
    ranked(oa, c, 1000)
    ranked(march, d, 50_000, when=datetime(2025, 2, 28, 23, 59, tzinfo=UTC))  # February
    unranked = Submission.objects.create(
        event=march, racer=a, model_name="m", status=Submission.Status.UNRANKED, created_at=IN_MARCH
    )
    assert unranked.score_ms is None
    assert divisions.monthly_standings(MARCH) == {}


def test_an_empty_month_promotes_nobody(db) -> None:
    result = divisions.divisions_promote(month=MARCH)
    assert (result.racers, result.promoted, result.newly_promoted) == (0, [], [])
    assert not DivisionMembership.objects.exists()
    assert not Notification.objects.exists()


def test_a_single_racer_is_promoted(march_event) -> None:
    (solo,) = racers(1)
    ranked(march_event, solo, 20_000)
    assert divisions.divisions_promote(month=MARCH).promoted == [solo.pk]


def test_promotion_is_idempotent(march_event) -> None:
    field = racers(10)
    for i, racer in enumerate(field):
        ranked(march_event, racer, 10_000 + i)
    first = divisions.divisions_promote(month=MARCH)
    second = divisions.divisions_promote(month=MARCH)
    assert first.newly_promoted == [field[0].pk]
    assert second.promoted == [field[0].pk] and second.newly_promoted == []
    assert DivisionMembership.objects.count() == 1
    assert Notification.objects.count() == 1


def test_command_and_beat_task(march_event, capsys) -> None:
    field = racers(3)
    for i, racer in enumerate(field):
        ranked(march_event, racer, 10_000 + i)
    call_command("promote_divisions", "--month", "2025-03")
    assert "1 newly promoted" in capsys.readouterr().out
    call_command("promote_divisions", "--month", "2025-03")
    assert "0 newly promoted" in capsys.readouterr().out
    assert promote_divisions.run(month="2025-03")["promoted"] == [field[0].pk]
    assert DivisionMembership.objects.count() == 1


def test_command_rejects_a_bad_month(db) -> None:
    from django.core.management.base import CommandError

    with pytest.raises(CommandError, match="not a month"):
        call_command("promote_divisions", "--month", "March")


def test_month_arithmetic() -> None:
    assert divisions.next_month(date(2025, 12, 1)) == date(2026, 1, 1)
    assert divisions.previous_month(date(2025, 1, 1)) == date(2024, 12, 1)
    assert divisions.month_start(datetime(2025, 3, 31, 23, 30, tzinfo=UTC)) == MARCH
