from django.apps import AppConfig


class LeaderboardConfig(AppConfig):
    """The league. ``ready`` connects the receivers that turn finished evaluations into
    results (leaderboard/signals.py)."""

    default_auto_field = "django.db.models.BigAutoField"
    name = "leaderboard"
    verbose_name = "League"

    def ready(self) -> None:
        from leaderboard import signals  # noqa: F401 - connects the receivers
