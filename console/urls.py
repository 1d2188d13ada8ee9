"""URL map of the console.

/                 home                  /tracks/            track gallery
/tracks/<id>.png  track preview         /models/, /league/  sections of later issues
/admin/           Django admin          /accounts/          login/logout (later issue)
"""

from __future__ import annotations

from django.contrib import admin
from django.urls import path, register_converter

from console import views


class TrackIdConverter:
    """Track ids as DeepRacer names them: letters, digits, underscores and hyphens."""

    regex = r"[A-Za-z0-9_-]+"

    def to_python(self, value: str) -> str:
        return value

    def to_url(self, value: str) -> str:
        return value


register_converter(TrackIdConverter, "track")

urlpatterns = [
    path("", views.home, name="home"),
    path("tracks/", views.track_gallery, name="track-gallery"),
    path("tracks/<track:track_id>.png", views.track_preview, name="track-preview"),
    path("models/", views.coming_soon, {"nav": "models", "title": "Models"}, name="models"),
    path("league/", views.coming_soon, {"nav": "league", "title": "League"}, name="league"),
    # path("accounts/", include("django.contrib.auth.urls")),  # login/logout: later issue
    path("admin/", admin.site.urls),
]
