"""Django admin of the training app: models and their jobs, for operators.

Jobs change state only through the services' compare-and-set (training/services/jobs.py), so
every job field is read-only here, and nothing is added or deleted from the admin. A model is
deleted in the console or with its services (its stored files go with it); here an operator
finds it, reads its state and may fix its name or description.
"""

from __future__ import annotations

from django.contrib import admin
from django.http import HttpRequest

from training.models import EvaluationJob, IterationMetric, RacingModel, TrainingJob


class ReadOnlyAdmin(admin.ModelAdmin):
    """Every field read-only; no adding, no deleting."""

    def get_readonly_fields(self, request: HttpRequest, obj=None):  # noqa: ANN001
        return [f.name for f in self.model._meta.fields]

    def has_add_permission(self, request: HttpRequest, obj=None) -> bool:  # noqa: ANN001
        return False

    def has_delete_permission(self, request: HttpRequest, obj=None) -> bool:  # noqa: ANN001
        return False


class TrainingJobInline(admin.TabularInline):
    model = TrainingJob
    fields = ("status", "created_at", "finished_at", "iterations", "episodes", "error")
    readonly_fields = fields
    extra = 0
    can_delete = False
    show_change_link = True

    def has_add_permission(self, request: HttpRequest, obj=None) -> bool:  # noqa: ANN001
        return False


class EvaluationJobInline(TrainingJobInline):
    model = EvaluationJob
    fields = ("status", "purpose", "track_id", "laps", "laps_done", "created_at", "error")
    readonly_fields = fields


@admin.register(RacingModel)
class RacingModelAdmin(admin.ModelAdmin):
    list_display = ("name", "owner", "status", "track_id", "algorithm", "action_space_type",
                    "has_checkpoint", "imported", "created_at")  # fmt: skip
    list_filter = ("status", "algorithm", "action_space_type", "imported", "has_checkpoint",
                   "track_id")  # fmt: skip
    search_fields = ("name", "description", "owner__username", "owner__email")
    list_select_related = ("owner",)
    date_hierarchy = "created_at"
    readonly_fields = ("owner", "track_id", "direction", "race_type", "sensors", "neural_network",
                       "action_space_type", "action_space", "algorithm", "hyperparameters",
                       "reward_function", "seed", "parent", "imported", "status",
                       "has_checkpoint", "error", "created_at", "updated_at")  # fmt: skip
    inlines = [TrainingJobInline, EvaluationJobInline]

    def has_add_permission(self, request: HttpRequest, obj=None) -> bool:  # noqa: ANN001
        return False

    def has_delete_permission(self, request: HttpRequest, obj=None) -> bool:  # noqa: ANN001
        return False  # the console deletes a model with its stored files


@admin.register(TrainingJob)
class TrainingJobAdmin(ReadOnlyAdmin):
    list_display = ("pk", "model", "owner", "status", "created_at", "started_at", "finished_at",
                    "iterations", "episodes", "stopped_by", "worker")  # fmt: skip
    list_filter = ("status", "stopped_by")
    search_fields = ("model__name", "model__owner__username", "worker", "task_id", "error")
    list_select_related = ("model", "model__owner")
    date_hierarchy = "created_at"

    @admin.display(ordering="model__owner__username")
    def owner(self, job: TrainingJob) -> str:
        return job.model.owner.get_username()


@admin.register(EvaluationJob)
class EvaluationJobAdmin(ReadOnlyAdmin):
    list_display = ("pk", "model", "owner", "status", "purpose", "track_id", "laps_done", "laps",
                    "created_at", "finished_at", "worker")  # fmt: skip
    list_filter = ("status", "purpose", "track_id")
    search_fields = ("model__name", "model__owner__username", "worker", "task_id", "error")
    list_select_related = ("model", "model__owner")
    date_hierarchy = "created_at"

    @admin.display(ordering="model__owner__username")
    def owner(self, job: EvaluationJob) -> str:
        return job.model.owner.get_username()


@admin.register(IterationMetric)
class IterationMetricAdmin(ReadOnlyAdmin):
    list_display = ("job", "iteration", "episodes", "train_reward", "train_progress",
                    "eval_progress", "is_best", "elapsed_s")  # fmt: skip
    list_filter = ("is_best",)
    search_fields = ("job__model__name",)
