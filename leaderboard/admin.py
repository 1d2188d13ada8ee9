"""Django admin of the league: events, seasons, racers, divisions, submissions."""

from __future__ import annotations

from django.contrib import admin

from leaderboard.models import (
    DivisionMembership,
    Event,
    EventEntrant,
    Notification,
    RacerProfile,
    Season,
    Submission,
)
from training.formatting import format_lap_ms


class EventInline(admin.TabularInline):
    model = Event
    fields = ("name", "track_id", "division", "opens_at", "closes_at")
    extra = 0
    show_change_link = True


@admin.register(Season)
class SeasonAdmin(admin.ModelAdmin):
    list_display = ("name", "starts_on", "ends_on")
    inlines = [EventInline]


class EntrantInline(admin.TabularInline):
    model = EventEntrant
    fields = ("racer", "joined_at", "removed_at")
    raw_id_fields = ("racer",)
    extra = 0


@admin.register(Event)
class EventAdmin(admin.ModelAdmin):
    list_display = ("name", "season", "division", "track_id", "race_type", "ranking_method",
                    "opens_at", "closes_at", "is_private", "organiser")  # fmt: skip
    list_filter = ("division", "race_type", "ranking_method", "is_private", "season")
    search_fields = ("name", "description", "track_id")
    date_hierarchy = "opens_at"
    raw_id_fields = ("organiser",)
    readonly_fields = ("created_at",)
    inlines = [EntrantInline]
    fieldsets = (
        (None, {"fields": ("name", "description", "season", "division", "organiser",
                           "is_private", "invite_token", "created_at")}),
        ("Track and schedule", {"fields": ("track_id", "direction", "race_type", "opens_at",
                                           "closes_at")}),
        ("Rules", {"fields": ("ranking_method", "min_laps", "max_laps", "off_track_penalty_s",
                              "collision_penalty_s", "max_resets",
                              "max_submissions_per_racer")}),
        ("Object avoidance and head-to-bot", {
            "classes": ("collapse",),
            "fields": ("number_of_objects", "randomize_objects", "bot_count", "bot_speed_mps",
                       "bot_lane_changes"),
        }),
    )  # fmt: skip

    def get_changeform_initial_data(self, request):
        initial = super().get_changeform_initial_data(request)
        initial.setdefault("organiser", request.user.pk)
        return initial


@admin.register(Submission)
class SubmissionAdmin(admin.ModelAdmin):
    list_display = ("id", "event", "racer", "model_name", "status", "time", "consecutive_laps",
                    "off_tracks", "collisions", "created_at")  # fmt: skip
    list_filter = ("status", "event__division", "event")
    search_fields = ("model_name", "racer__username", "event__name")
    raw_id_fields = ("racer", "model", "evaluation", "event")
    readonly_fields = ("created_at", "finished_at", "laps")
    date_hierarchy = "created_at"

    @admin.display(description="Time", ordering="score_ms")
    def time(self, obj: Submission) -> str:
        return format_lap_ms(obj.score_ms)


@admin.register(RacerProfile)
class RacerProfileAdmin(admin.ModelAdmin):
    list_display = ("alias", "user", "country", "colour")
    search_fields = ("alias", "user__username")
    raw_id_fields = ("user",)


@admin.register(DivisionMembership)
class DivisionMembershipAdmin(admin.ModelAdmin):
    list_display = ("racer", "month", "division", "reason", "created_at")
    list_filter = ("division", "month")
    search_fields = ("racer__username",)
    raw_id_fields = ("racer",)


@admin.register(Notification)
class NotificationAdmin(admin.ModelAdmin):
    list_display = ("user", "message", "created_at", "read_at")
    search_fields = ("user__username", "message")
    raw_id_fields = ("user",)
