"""League URLs, included at /league/ by console/urls.py.

/league/                                   home: seasons, open events, notifications, profile
/league/events/new/                        a league event (race facilitators)
/league/community/new/                     a community race (any racer)
/league/events/<id>/                       the leaderboard (?screen=1: wide-screen mode)
/league/events/<id>/screen/                wide-screen mode
/league/events/<id>/edit|submit|close|invite/reset/
/league/events/<id>/participants/<racer>/remove/
/league/join/<token>/                      a community race's invite link
/league/submissions/<id>/[video.mp4]       a submission's lap table and video
/league/events/<id>/bracket/               the head-to-head bracket (seed, withdraw)
/league/events/<id>/race-day/              the facilitator's race-day queue and controls
/league/events/<id>/speed/                 a racer's live speed control during their turn
/league/events/<id>/speed/turn.json        whose turn it is, for that page's poll
/league/events/<id>/broadcast/[?watch=]    the broadcast page for a big screen
/league/races/<id>/video.mp4               a league race's broadcast video
Websockets: /ws/league/events/<id>/ and /ws/league/events/<id>/broadcast/ (routing.py)
"""

from __future__ import annotations

from django.urls import path

from leaderboard import raceviews, speedviews, views

urlpatterns = [
    path("", views.league_home, name="league"),
    path("events/new/", views.event_create, name="league-event-create"),
    path("community/new/", views.community_create, name="league-community-create"),
    path("events/<int:event_id>/", views.event_detail, name="league-event"),
    path("events/<int:event_id>/screen/", views.event_screen, name="league-event-screen"),
    path("events/<int:event_id>/edit/", views.event_edit, name="league-event-edit"),
    path("events/<int:event_id>/submit/", views.event_submit, name="league-event-submit"),
    path("events/<int:event_id>/close/", views.event_close, name="league-event-close"),
    path(
        "events/<int:event_id>/invite/reset/",
        views.event_invite_reset,
        name="league-event-invite-reset",
    ),
    path(
        "events/<int:event_id>/participants/<int:racer_id>/remove/",
        views.event_participant_remove,
        name="league-participant-remove",
    ),
    path("join/<str:token>/", views.event_join, name="league-join"),
    path("events/<int:event_id>/bracket/", raceviews.event_bracket, name="league-event-bracket"),
    path("events/<int:event_id>/race-day/", raceviews.race_day, name="league-race-day"),
    path("events/<int:event_id>/speed/", speedviews.race_speed, name="league-race-speed"),
    path(
        "events/<int:event_id>/speed/turn.json",
        speedviews.race_speed_turn,
        name="league-race-speed-turn",
    ),
    path("events/<int:event_id>/broadcast/", raceviews.broadcast, name="league-broadcast"),
    path("races/<int:race_id>/video.mp4", raceviews.race_video_view, name="league-race-video"),
    path("submissions/<int:submission_id>/", views.submission_detail, name="league-submission"),
    path(
        "submissions/<int:submission_id>/video.mp4",
        views.submission_video,
        name="league-submission-video",
    ),
]
