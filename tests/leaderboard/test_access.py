"""Who may see and enter what: Open/Pro divisions, community races behind invite links
(expiry at close, reset keeps entrants, removal), organiser powers, the racer alias."""

from __future__ import annotations

from datetime import timedelta

import pytest
from django.utils import timezone
from league_helpers import make_event, make_model

from leaderboard import divisions, events
from leaderboard.access import LeagueError, can_view_event
from leaderboard.models import Division, DivisionMembership, EventEntrant
from leaderboard.profiles import profile_update
from leaderboard.services import submission_create

pytestmark = pytest.mark.django_db


def make_pro(user) -> None:
    DivisionMembership.objects.create(racer=user, month=divisions.month_start(),
                                      division=Division.PRO)  # fmt: skip


@pytest.fixture
def community(alice):
    return events.event_create(
        organiser=alice, is_private=True, name="Friday night", track_id="racecraft_oval",
        opens_at=timezone.now() - timedelta(minutes=5),
        closes_at=timezone.now() + timedelta(days=1),
    )  # fmt: skip


# ------------------------------------------------------------------ divisions
def test_open_racers_cannot_enter_pro_events_and_pro_racers_cannot_enter_open(alice, bob, fran):
    open_event = make_event(fran, name="Open TT")
    pro_event = make_event(fran, name="Pro TT", division=Division.PRO)
    make_pro(bob)
    events.event_entry_check(event=open_event, user=alice)
    events.event_entry_check(event=pro_event, user=bob)
    with pytest.raises(LeagueError, match="Pro division event and you race in Open"):
        events.event_entry_check(event=pro_event, user=alice)
    with pytest.raises(LeagueError, match="Open division event and you race in Pro"):
        events.event_entry_check(event=open_event, user=bob)
    # watching is allowed both ways
    assert can_view_event(alice, pro_event) and can_view_event(bob, open_event)


def test_only_facilitators_create_public_events(alice, fran):
    fields = {"name": "X", "track_id": "racecraft_oval", "opens_at": timezone.now(),
              "closes_at": timezone.now() + timedelta(days=1)}  # fmt: skip
    with pytest.raises(LeagueError, match="only race facilitators"):
        events.event_create(organiser=alice, is_private=False, **fields)
    assert not events.event_create(organiser=fran, is_private=False, **fields).is_private


@pytest.mark.parametrize(
    ("change", "message"),
    [({"min_laps": 4, "max_laps": 3}, "minimum ≤ maximum"),
     ({"track_id": "no_such_track"}, "unknown track"),
     ({"closes_at": timezone.now() - timedelta(days=9)}, "open before it closes"),
     ({"name": "  "}, "name")],
)  # fmt: skip
def test_event_rules_are_checked(fran, change, message):
    fields = {"name": "X", "track_id": "racecraft_oval", "opens_at": timezone.now(),
              "closes_at": timezone.now() + timedelta(days=1), **change}  # fmt: skip
    with pytest.raises(LeagueError, match=message):
        events.event_create(organiser=fran, is_private=False, **fields)


# ------------------------------------------------------------------ community races
def test_a_private_race_is_reached_only_through_its_link(community, alice, bob, charlie, client):
    assert not can_view_event(bob, community)
    client.force_login(bob)
    assert client.get(f"/league/events/{community.pk}/").status_code == 404
    with pytest.raises(LeagueError, match="private race"):
        events.event_entry_check(event=community, user=bob)
    # the league home does not list it for outsiders
    assert "Friday night" not in client.get("/league/").content.decode()

    page = client.get(f"/league/join/{community.invite_token}/")
    assert page.status_code == 200 and "Join the race" in page.content.decode()
    response = client.post(f"/league/join/{community.invite_token}/")
    assert response.status_code == 302
    assert client.get(f"/league/events/{community.pk}/").status_code == 200
    events.event_entry_check(event=community, user=bob)
    assert not can_view_event(charlie, community)


def test_division_does_not_apply_to_community_races(community, bob):
    make_pro(bob)
    events.event_join(token=community.invite_token, user=bob)
    events.event_entry_check(event=community, user=bob)


def test_the_invite_link_expires_at_close(community, bob, client):
    events.event_close(event=community, user=community.organiser)
    with pytest.raises(LeagueError, match="expired"):
        events.event_join(token=community.invite_token, user=bob)
    client.force_login(bob)
    response = client.get(f"/league/join/{community.invite_token}/")
    assert response.status_code == 404 and "expired" in response.content.decode()


def test_resetting_the_link_keeps_entrants(community, alice, bob, charlie):
    old = community.invite_token
    events.event_join(token=old, user=bob)
    with pytest.raises(LeagueError, match="only the organiser"):
        events.event_invite_reset(event=community, user=bob)
    events.event_invite_reset(event=community, user=alice)
    community.refresh_from_db()
    assert community.invite_token != old
    with pytest.raises(LeagueError, match="not valid"):
        events.event_join(token=old, user=charlie)
    assert can_view_event(bob, community)  # still in
    events.event_join(token=community.invite_token, user=charlie)
    assert can_view_event(charlie, community)


def test_the_organiser_removes_participants_who_cannot_rejoin(community, alice, bob):
    events.event_join(token=community.invite_token, user=bob)
    with pytest.raises(LeagueError, match="only the organiser"):
        events.event_participant_remove(event=community, user=bob, racer=alice)
    events.event_participant_remove(event=community, user=alice, racer=bob)
    assert not can_view_event(bob, community)
    with pytest.raises(LeagueError, match="removed you"):
        events.event_join(token=community.invite_token, user=bob)
    assert EventEntrant.objects.filter(event=community).count() == 2


def test_organiser_edits_and_closes_early(community, alice, bob):
    events.event_update(event=community, user=alice, name="Saturday night", division="PRO")
    community.refresh_from_db()
    assert community.name == "Saturday night" and community.division == Division.OPEN
    with pytest.raises(LeagueError, match="only the organiser"):
        events.event_update(event=community, user=bob, name="Mine")
    with pytest.raises(LeagueError, match="only the organiser"):
        events.event_close(event=community, user=bob)
    events.event_close(event=community, user=alice)
    assert community.is_closed()
    with pytest.raises(LeagueError, match="already closed"):
        events.event_close(event=community, user=alice)


def test_scoring_rules_are_fixed_after_the_first_submission(event, fran, alice):
    submission_create(event=event, user=alice, model=make_model(alice))
    with pytest.raises(LeagueError, match="can no longer change"):
        events.event_update(event=event, user=fran, min_laps=2)
    events.event_update(event=event, user=fran, name="Renamed", max_submissions_per_racer=5)


# ------------------------------------------------------------------ profile
def test_an_alias_is_chosen_once(db, alice, bob):
    from league_helpers import make_user

    dave = make_user("dave")
    with pytest.raises(LeagueError, match="taken"):
        profile_update(user=dave, alias="alice-r")  # case-insensitive
    with pytest.raises(LeagueError, match="3-32"):
        profile_update(user=dave, alias="x")
    profile = profile_update(user=dave, alias="DaveDrives", country="de", colour="#00AAFF")
    assert (profile.alias, profile.country, profile.colour) == ("DaveDrives", "DE", "#00aaff")
    with pytest.raises(LeagueError, match="fixed"):
        profile_update(user=dave, alias="Another")
    assert profile_update(user=dave, alias="", country="BR").alias == "DaveDrives"
