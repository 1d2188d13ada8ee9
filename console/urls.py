"""URL map of the console.

/                          home                 /tracks/, /tracks/<id>.png   track gallery
/tracks/<id>/race.png      a race's objects on the track (query: the race settings, direction)
/accounts/signup|login|logout/                  /admin/                      Django admin
/models/                   your models          /models/new/, /models/import/[bucket/]
/models/<id>/              a model's page       .../clone/, .../delete/, .../train/, .../reward/
/models/<id>/download/<car|virtual|logs>/       /evaluations/<id>/video.mp4
/models/<id>/analysis/     charts of the logs   .../data/<chart>.<json|csv>, .../replay/
/jobs/training/<id>/stop/  /evaluations/<id>/stop/                           stop a job
/api/reward/validate       the reward function's Validate button (JSON)
/api/openapi.json          the JSON API's OpenAPI description (console/openapi.json)
/races/, /races/new/, /races/<id>/[video.mp4|traces.tar.gz|stop/]   racers race each other
/league/                   the league (leaderboard app)
/help/, /help/<guide>/     the guides in docs/ (console/helpdocs.py)
"""

from __future__ import annotations

from django.contrib import admin
from django.contrib.auth import views as auth_views
from django.templatetags.static import static
from django.urls import include, path, register_converter
from django.views.generic.base import RedirectView

from console.views import accounts, analysis, api, downloads, model_page, models, pages
from console.views import help as help_views
from console.views import races as race_views
from console.views import readiness as readiness_views


class TrackIdConverter:
    """Track ids as DeepRacer names them: letters, digits, underscores and hyphens."""

    regex = r"[A-Za-z0-9_-]+"

    def to_python(self, value: str) -> str:
        return value

    def to_url(self, value: str) -> str:
        return value


register_converter(TrackIdConverter, "track")

urlpatterns = [
    path("", pages.home, name="home"),
    path("tracks/", pages.track_gallery, name="track-gallery"),
    path("tracks/<track:track_id>.png", pages.track_preview, name="track-preview"),
    path("tracks/<track:track_id>/race.png", pages.track_race_preview, name="track-race-preview"),
    path(
        "tracks/<track:track_id>/conditions/<int:index>.png",
        pages.track_conditions_preview,
        name="track-conditions-preview",
    ),
    path("tracks/import/", pages.track_upload, name="track-upload"),
    # accounts
    path("accounts/signup/", accounts.signup, name="signup"),
    path(
        "accounts/login/",
        # A new session lands on the user's models (a ?next= link still wins).
        auth_views.LoginView.as_view(redirect_authenticated_user=True, next_page="models"),
        name="login",
    ),
    path("accounts/logout/", auth_views.LogoutView.as_view(next_page="home"), name="logout"),
    # models
    path("models/", models.model_list, name="models"),
    path("models/new/", models.model_create, name="model-create"),
    path("models/import/", models.model_import, name="model-import"),
    path("models/import/bucket/", models.model_import_bucket, name="model-import-bucket"),
    path("models/<int:model_id>/", model_page.model_detail, name="model-detail"),
    path("models/<int:model_id>/clone/", models.model_clone, name="model-clone"),
    path("models/<int:model_id>/delete/", models.model_delete, name="model-delete"),
    path("models/<int:model_id>/reward/", models.model_reward_edit, name="model-reward-edit"),
    path("models/<int:model_id>/train/", model_page.training_start, name="training-start"),
    path("models/<int:model_id>/evaluate/", model_page.evaluation_start, name="evaluation-start"),
    path(
        "models/<int:model_id>/download/<str:kind>/",
        downloads.model_download,
        name="model-download",
    ),
    path("models/<int:model_id>/analysis/", analysis.analysis_page, name="model-analysis"),
    path(
        "models/<int:model_id>/analysis/data/<str:chart>.<str:fmt>",
        analysis.analysis_data,
        name="analysis-data",
    ),
    path(
        "models/<int:model_id>/analysis/episode/<int:iteration>/<int:episode>/",
        analysis.analysis_episode,
        name="analysis-episode",
    ),
    path("models/<int:model_id>/analysis/replay/", analysis.replay_start, name="replay-start"),
    path(
        "models/<int:model_id>/analysis/replay/<str:task_id>/",
        analysis.replay_result,
        name="replay-result",
    ),
    path("jobs/training/<int:job_id>/stop/", model_page.training_stop, name="training-stop"),
    path(
        "evaluations/<int:evaluation_id>/stop/", model_page.evaluation_stop, name="evaluation-stop"
    ),
    path(
        "evaluations/<int:evaluation_id>/video.mp4",
        downloads.evaluation_video,
        name="evaluation-video",
    ),
    # readiness for the real car (issue 51)
    path(
        "models/<int:model_id>/readiness/", readiness_views.readiness_start, name="readiness-start"
    ),
    path("readiness/<int:check_id>/stop/", readiness_views.readiness_stop, name="readiness-stop"),
    path(
        "readiness/<int:check_id>/progress.json",
        readiness_views.readiness_progress,
        name="readiness-progress",
    ),
    path(
        "readiness/<int:check_id>/video/<slug:key>.mp4",
        readiness_views.readiness_video,
        name="readiness-video",
    ),
    path("readiness/compare/", readiness_views.readiness_compare, name="readiness-compare"),
    path("api/reward/validate", api.reward_validate, name="reward-validate"),
    path("api/tasks/<str:task_id>", api.background_task, name="background-task"),
    path("api/openapi.json", api.openapi_schema, name="openapi-schema"),
    # races between racers (console/views/races.py)
    path("races/", race_views.race_list, name="races"),
    path("races/new/", race_views.race_new, name="race-new"),
    path("races/<int:race_id>/", race_views.race_detail, name="race-detail"),
    path("races/<int:race_id>/video.mp4", race_views.race_video_view, name="race-video"),
    path("races/<int:race_id>/traces.tar.gz", race_views.race_traces, name="race-traces"),
    path("races/<int:race_id>/stop/", race_views.race_stop_view, name="race-stop"),
    path(
        "models/<int:model_id>/challenges/", race_views.model_challenges, name="model-challenges"
    ),  # fmt: skip
    path("league/", include("leaderboard.urls")),
    # help: the guides in docs/, rendered
    path("help/", help_views.help_index, name="help"),
    path("help/<slug:slug>/", help_views.help_guide, name="help-guide"),
    path("admin/", admin.site.urls),
    # Browsers ask for /favicon.ico on pages without an icon link (the admin's).
    path("favicon.ico", RedirectView.as_view(url=static("img/logo.svg"), permanent=True)),
]
