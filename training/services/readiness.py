"""Readiness checks (issue 51): the owner's side (start one, read its videos, compare two
models) and the worker's (record the table). The check itself is
:func:`training.rl.readiness.check_readiness`; the job runs on the ``readiness`` queue
(:mod:`training.worker.readiness`) and, like an evaluation, counts against its owner's quota
(``RACECRAFT_MAX_ACTIVE_JOBS_PER_USER``) and takes its turn in the fair order
(:mod:`training.services.job_queue`). Stopping and failures are the job state machine's
(:mod:`training.services.jobs`)."""

from __future__ import annotations

from django.db import transaction

from training import dispatch
from training.errors import ServiceError
from training.http import Media
from training.models import JobStatus, RacingModel, ReadinessCheck
from training.rl.readiness import ReadinessError, ReadinessPlan, cell_key
from training.services.checks import check_track
from training.services.job_states import enqueue_after_commit, model_has_active_jobs, owned
from training.services.jobs import job_quota_hold
from training.services.model_files import store_failure
from training.services.trackfiles import tracks_check_recorded
from training.storage import StoreError
from training.store import get_store, keys_for


def readiness_plan(data: dict | None = None) -> ReadinessPlan:
    """A plan from a form's or a caller's dict (the defaults when empty); raises
    :class:`ServiceError` with the rule it breaks."""
    try:
        return ReadinessPlan.from_dict(data or {})
    except (ReadinessError, TypeError, ValueError) as exc:
        raise ServiceError(f"readiness check: {exc}") from None


def readiness_start(
    *,
    model: RacingModel,
    user,
    track_id: str | None = None,
    direction: str | None = None,
    plan: dict | None = None,
    enqueue: bool = True,
) -> ReadinessCheck:
    """Queue a readiness check of ``model``'s best checkpoint on ``track_id`` (the model's
    own track and direction by default). Refused: someone else's model ("not found"), a model
    without a checkpoint, a busy model, a full quota (:class:`JobQuotaError`)."""
    owned(model, user)
    track_id = track_id or model.track_id
    direction = direction or model.direction
    check_track(track_id, direction)
    tracks_check_recorded([track_id])
    checked = readiness_plan(plan)
    with transaction.atomic():
        job_quota_hold(user=user)
        model = RacingModel.objects.select_for_update().get(pk=model.pk)
        if not model.has_checkpoint:
            raise ServiceError("train this model before checking its readiness")
        if model_has_active_jobs(model):
            raise ServiceError("this model is busy; wait for its current job to finish")
        check = ReadinessCheck.objects.create(
            model=model, track_id=track_id, direction=direction, plan=checked.to_dict(),
            cells_total=len(checked.cells()),
        )  # fmt: skip
        model.status = RacingModel.Status.EVALUATING
        model.save(update_fields=["status", "updated_at"])
        if enqueue:
            enqueue_after_commit(check, dispatch.CHECK_READINESS)
    return check


def readiness_video_id(check: ReadinessCheck, key: str) -> str:
    """The id of a worst cell's MP4 under the model's ``videos/`` folder."""
    return f"readiness{check.pk}-{key}"


def readiness_video_key(check: ReadinessCheck, key: str) -> str:
    """The object key of the MP4 of cell ``key``: always inside the check's model's folder."""
    return keys_for(check.model_id).video(readiness_video_id(check, key))


def readiness_video(check: ReadinessCheck, key: str) -> Media:
    """The MP4 of the worst cell ``key`` of a finished check, as ranged reads from the store
    (never loaded whole); ServiceError when it has none."""
    if key not in (check.videos or []):
        raise ServiceError("this readiness check has no such video")
    store, stored = get_store(), readiness_video_key(check, key)
    try:
        size = store.stat_size(stored)
    except StoreError as exc:
        raise store_failure(exc, "the video could not be read") from None
    return Media(size, lambda start, length: store.get_range(stored, start, length))


def readiness_latest(model: RacingModel) -> ReadinessCheck | None:
    return model.readiness_checks.order_by("-created_at", "-pk").first()


def readiness_finished_models(user) -> list[RacingModel]:
    """The user's models with a completed check, newest first: what the compare page offers."""
    ids = (
        ReadinessCheck.objects.filter(model__owner=user, status=JobStatus.COMPLETED)
        .values_list("model_id", flat=True)
        .distinct()
    )
    return list(RacingModel.objects.filter(pk__in=list(ids)).order_by("name"))


def readiness_compare(
    *, user, model_ids: list[int | None]
) -> list[tuple[RacingModel, ReadinessCheck]]:
    """Each model's latest completed check, for a side-by-side table; only ``user``'s own
    models (another's is "not found"), each with a finished check."""
    if len(model_ids) != 2 or None in model_ids or model_ids[0] == model_ids[1]:
        raise ServiceError("pick two different models to compare")
    pairs = []
    for model_id in model_ids:
        model = RacingModel.objects.filter(pk=model_id, owner=user).first()
        if model is None:
            raise ServiceError("not found")
        check = (
            model.readiness_checks.filter(status=JobStatus.COMPLETED)
            .order_by("-finished_at", "-pk")
            .first()
        )
        if check is None:
            raise ServiceError(f"{model.name} has no finished readiness check")
        pairs.append((model, check))
    return pairs


def readiness_rows(checks: list[ReadinessCheck]) -> list[dict]:
    """Rows for a table of one or more checks side by side: per cell (the first check's cells
    in order, then any the others add), each check's cell or None."""
    order: list[str] = []
    by_check: list[dict[str, dict]] = []
    for check in checks:
        cells = {cell_key(c["family"], c["strength"]): c for c in check.cells}
        by_check.append(cells)
        order += [k for k in cells if k not in order]
    rows = []
    for key in order:
        first = next(c[key] for c in by_check if key in c)
        rows.append({"key": key, "family": first["family"], "strength": first["strength"],
                     "cells": [c.get(key) for c in by_check]})  # fmt: skip
    return rows


def readiness_for_owner(user, check_id: int) -> ReadinessCheck:
    """The check ``check_id`` of one of ``user``'s models; raises
    ``ReadinessCheck.DoesNotExist`` for anyone else's, as for a missing one."""
    return ReadinessCheck.objects.select_related("model").get(pk=check_id, model__owner=user)


def readiness_grid(check: ReadinessCheck | None) -> dict | None:
    """A finished (or stopped) check's table as the page shows it: the clean baseline, then
    one row per family with one cell per strength (None where the check did not get there)."""
    if check is None or not check.cells:
        return None
    plan = readiness_plan(check.plan)
    cells = {cell_key(c["family"], c["strength"]): c for c in check.cells}
    worst = set(check.results.get("worst", []))
    rows = [
        {"family": family,
         "cells": [cells.get(cell_key(family, s)) for s in plan.strengths]}
        for family in plan.families
    ]  # fmt: skip
    for row in rows:
        for cell in row["cells"]:
            if cell is not None:
                cell["worst"] = cell_key(cell["family"], cell["strength"]) in worst
    return {"strengths": list(plan.strengths), "baseline": cells.get(cell_key("clean", 0.0)),
            "rows": rows}  # fmt: skip
