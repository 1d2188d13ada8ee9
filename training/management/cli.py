"""What the ``racecraft_*`` commands share: service errors as CommandErrors, running a job in
this process with a progress bar, following a queued job, and the evaluation results table.

A job run inline goes through the same code as a Celery worker
(:func:`training.worker.training.run_training_job`), in a background thread; the main thread
polls the database, draws the bar and turns Ctrl-C into a stop request (``stop_requested``), so
the job ends cleanly and keeps its last checkpoint. Sandboxed rollout workers run in their own
session, so a Ctrl-C on the terminal does not reach them.
"""

from __future__ import annotations

import logging
import os
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from django.core.management.base import CommandError, OutputWrapper
from django.db import connections

from racing.rules import STATUS_LABELS, Status
from training import services
from training.formatting import format_lap_s
from training.management.progress import ProgressBar
from training.models import (
    FINISHED_JOB_STATUSES,
    EvaluationJob,
    IterationMetric,
    JobStatus,
    TrainingJob,
)
from training.selectors import model_for_cli, user_by_username
from training.services import RewardRejected, ServiceError

POLL_S = 0.5
"""Seconds between two looks at the job's row."""

Job = TrainingJob | EvaluationJob


def pause(seconds: float) -> None:
    """Wait between two looks at a job; a Ctrl-C usually arrives here, as KeyboardInterrupt
    (tests replace this function to press Ctrl-C). Not ``Thread.join``: interrupted, it can
    leave the thread looking finished while it still runs."""
    time.sleep(seconds)


def reward_error_lines(errors: list[dict]) -> list[str]:
    """``line N: TYPE: message`` for each DeepRacer-style reward error."""
    lines = []
    for error in errors:
        where = f"line {error['line']}: " if error.get("line") else ""
        lines.append(f"{where}{error.get('type', 'ERROR')}: {error.get('message', '')}")
    return lines


@contextmanager
def service_errors(what: str = "") -> Iterator[None]:
    """Turn a :class:`ServiceError` into a :class:`CommandError` (exit code 1) with its
    message; a rejected reward function lists every error with its line."""
    prefix = f"{what}: " if what else ""
    try:
        yield
    except RewardRejected as exc:
        details = "\n".join(f"  {line}" for line in reward_error_lines(exc.errors))
        raise CommandError(f"{prefix}the reward function was rejected:\n{details}") from None
    except ServiceError as exc:
        raise CommandError(f"{prefix}{exc.message}") from None


def mmss(seconds: float) -> str:
    """``mm:ss`` (minutes may pass 59)."""
    seconds = max(0, int(seconds))
    return f"{seconds // 60:02d}:{seconds % 60:02d}"


def _refresh(job: Job) -> Job:
    return type(job).objects.select_related("model").get(pk=job.pk)


# ------------------------------------------------------------------------------ progress text
def training_progress(job: TrainingJob) -> tuple[float, str]:
    """Fraction of the stop condition used, and ``mm:ss/mm:ss  iteration n running  e
    episodes  eval x%  best y%``: the clock moves on every redraw, the counts after each
    iteration (an iteration is ``num_episodes_between_training`` episodes, then an update)."""
    limit_s = job.max_minutes * 60
    if job.status == JobStatus.QUEUED:
        return 0.0, "queued"
    parts = [f"{mmss(job.elapsed_seconds)}/{mmss(limit_s)}"]
    latest = IterationMetric.objects.filter(job=job).order_by("-iteration").first()
    per_iteration = (job.model.hyperparameters or {}).get("num_episodes_between_training")
    if job.status == JobStatus.INITIALIZING:
        parts.append("starting the simulators")
    elif job.status in (JobStatus.IN_PROGRESS, JobStatus.STOPPING):
        done = latest.iteration if latest else 0
        size = f" ({per_iteration} episodes + update)" if per_iteration and not latest else ""
        parts.append(f"iteration {done + 1} running{size}")
    elif latest is not None:
        parts.append(f"{latest.iteration} iterations")
    parts.append(f"{job.episodes} episodes")
    if latest is not None:
        parts.append(f"eval {latest.eval_progress:.1f}%")
        parts.append(f"best {job.best_eval_progress:.1f}%")
    if job.status == JobStatus.STOPPING:
        parts.append("stopping")
    return job.elapsed_seconds / limit_s, "  ".join(parts)


def evaluation_progress(job: EvaluationJob) -> tuple[float, str]:
    """Fraction of the laps done, and ``mm:ss  laps 1/3``."""
    if job.status == JobStatus.QUEUED:
        return 0.0, "queued"
    text = f"{mmss(job.elapsed_seconds)}  laps {job.laps_done}/{job.laps}"
    if job.status == JobStatus.STOPPING:
        text += "  stopping"
    return job.laps_done / max(1, job.laps), text


def results_table(job: EvaluationJob) -> str:
    """The evaluation's laps as DeepRacer's results table (plain text, aligned columns)."""
    header = ("Trial", "Time", "Progress", "Status", "Off-tracks", "Crashes", "Resets")
    rows = [header]
    for lap in job.lap_rows:
        try:
            status = STATUS_LABELS[Status(lap["status"])]
        except (KeyError, ValueError):
            status = str(lap.get("status", ""))
        rows.append((
            str(lap.get("trial", "")),
            format_lap_s(float(lap.get("time_s", 0.0))),
            f"{float(lap.get('progress', 0.0)):.1f}%",
            status,
            f"{lap.get('off_tracks', 0)} (+{float(lap.get('off_track_penalty_s', 0)):g} s)",
            f"{lap.get('crashes', 0)} (+{float(lap.get('crash_penalty_s', 0)):g} s)",
            str(lap.get("resets", 0)),
        ))  # fmt: skip
    widths = [max(len(row[i]) for row in rows) for i in range(len(header))]
    return "\n".join(
        "  ".join(cell.ljust(width) for cell, width in zip(row, widths, strict=True)).rstrip()
        for row in rows
    )


# ------------------------------------------------------------------------------ running jobs
def worker_name() -> str:
    """What the job row records as its worker: this command on this host."""
    return f"cli-{os.getpid()}@{socket.gethostname()}"


def run_inline(
    *,
    job: Job,
    user,
    run: Callable[[int, str], str],
    progress: Callable[[Job], tuple[float, str]],
    out: OutputWrapper,
    tty: bool | None = None,
) -> Job:
    """Run ``run(job_id, worker)`` (a task body from :mod:`training.worker`) in a thread of
    this process, with a progress bar. The first Ctrl-C asks the job to stop and waits for its clean
    end; a second one gives up on it (the job is marked failed). Returns the finished row."""
    failure: list[BaseException] = []
    finished = threading.Event()

    def body() -> None:
        try:
            run(job.pk, worker_name())
        except BaseException as exc:  # noqa: BLE001 - handed to the main thread
            failure.append(exc)
        finally:
            connections.close_all()  # this thread's connections only
            finished.set()

    thread = threading.Thread(target=body, name=f"racecraft-job-{job.pk}", daemon=True)
    bar = ProgressBar(out, tty=tty)
    try:
        with quiet_live_updates():
            thread.start()
            _watch(finished, job, user, progress, bar, out)
        thread.join(timeout=10)  # it has set `finished`: only its last lines are left
    finally:
        bar.close()
    if failure:
        raise CommandError(f"job {job.pk} crashed: {failure[0]!r}")
    return _refresh(job)


def _watch(
    finished: threading.Event,
    job: Job,
    user,
    progress: Callable[[Job], tuple[float, str]],
    bar: ProgressBar,
    out: OutputWrapper,
) -> None:
    """Draw the bar until the job's thread ends. A Ctrl-C may land anywhere in the loop, even
    while the previous one is handled: it is only counted there, and acted on at the next
    turn (the first asks the job to stop, the second gives up on it)."""
    interrupts = stop_sent = 0
    while not finished.is_set():
        try:
            if interrupts >= 2:
                give_up(job)
            if interrupts == 1 and not stop_sent:
                stop_sent = 1
                out.write(
                    "Stopping: the job ends at its next safe point and keeps what it has done "
                    "(a training its last checkpoint, an evaluation its laps). Press Ctrl-C "
                    "again to give up on it at once."
                )
                _request_stop(job, user)
            pause(POLL_S)
            bar.update(*progress(_refresh(job)))
        except KeyboardInterrupt:
            interrupts += 1
            bar.close()
    bar.update(*progress(_refresh(job)))


def give_up(job: Job) -> None:
    """Mark the job failed and leave the process at once, with exit code 1; the job's
    thread dies with it, and the sandboxed workers die with their parent."""
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        services.job_fail(job=job, error="abandoned from the command line (Ctrl-C)")
    finally:
        signal.signal(signal.SIGINT, previous)
    sys.stderr.write(
        f"Gave up on job {job.pk}: it is marked failed; what it stored so far is kept.\n"
    )
    exit_now(1)


def exit_now(code: int) -> None:
    """Exit without waiting for the job's thread (torch aborts if finalised under a running
    thread). Tests replace this function."""
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


@contextmanager
def quiet_live_updates() -> Iterator[None]:
    """Live updates are for browsers watching the job; without Redis (a command run with no
    console up) each one would log a traceback. Only errors are logged meanwhile."""
    logger = logging.getLogger("training.live")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        yield
    finally:
        logger.setLevel(level)


def _request_stop(job: Job, user) -> None:
    try:
        services.job_stop(job=_refresh(job), user=user)
    except ServiceError:
        pass  # it finished in the meantime


def follow_queued(
    *,
    job: Job,
    progress: Callable[[Job], tuple[float, str]],
    out: OutputWrapper,
    tty: bool | None = None,
) -> Job | None:
    """Follow a job run by a Celery worker until it ends; ``None`` when the user stopped
    following it (Ctrl-C), which leaves the job running."""
    bar = ProgressBar(out, tty=tty)
    try:
        while True:
            current = _refresh(job)
            bar.update(*progress(current))
            if current.status in FINISHED_JOB_STATUSES:
                return current
            try:
                pause(POLL_S)
            except KeyboardInterrupt:
                bar.close()
                out.write(
                    f"Stopped following job {job.pk}; it goes on in the worker "
                    "(stop it from the console)."
                )
                return None
    finally:
        bar.close()


def run_or_follow(
    *,
    job: Job,
    queue: bool,
    user,
    run: Callable[[int, str], str],
    progress: Callable[[Job], tuple[float, str]],
    out: OutputWrapper,
) -> Job | None:
    """Follow a queued job, or run it here; the finished job, or None if the user stopped
    following a queued one."""
    if queue:
        return follow_queued(job=job, progress=progress, out=out)
    return run_inline(job=job, user=user, run=run, progress=progress, out=out)


def job_outcome(job: Job) -> str:
    """``Completed``, ``Failed: why``, ``Canceled``... for the last line of a command."""
    text = job.get_status_display()
    return f"{text}: {job.error}" if job.error else text


def require_completed(job: Job, what: str) -> None:
    if job.status != JobStatus.COMPLETED:
        raise CommandError(f"{what} {job.pk} ended {job_outcome(job)}")


# ------------------------------------------------------------------------------ arguments
def add_owner_argument(parser, *, required: bool) -> None:
    parser.add_argument(
        "--owner",
        metavar="USERNAME",
        required=required,
        help="the user who owns the model"
        + ("" if required else " (checked when given; default: the model's owner)"),
    )


def add_model_arguments(parser) -> None:
    """``MODEL_ID`` and an optional ``--owner``, read back with :func:`owner_and_model`."""
    parser.add_argument("model_id", type=int, metavar="MODEL_ID")
    add_owner_argument(parser, required=False)


def add_queue_argument(parser, *, what: str) -> None:
    """``--queue``: a worker runs the ``what`` (job, evaluation) and the command follows it."""
    parser.add_argument(
        "--queue",
        action="store_true",
        help=f"queue the {what} for a Celery worker and follow it, instead of running it here",
    )


def add_track_argument(parser, *, default: str | None) -> None:
    """``--track``, with the installed track ids as its choices (listed in ``--help``, and by
    argparse when an unknown one is given)."""
    ids = services.track_catalog().ids()
    parser.add_argument(
        "--track",
        choices=ids,
        default=default,
        metavar="TRACK",
        help=f"track id, one of: {', '.join(ids)} "
        + (f"(default: {default})" if default else "(default: the model's training track)"),
    )


def action_summary(model) -> str:  # noqa: ANN001
    """``3 discrete actions`` or ``continuous actions (steering -30..30°, speed 0.5..2 m/s)``."""
    if model.action_space_type == "discrete":
        n = len(model.action_space)
        return f"{n} discrete action{'s' if n != 1 else ''}"
    try:
        steer, speed = model.action_space["steering_angle"], model.action_space["speed"]
        return (
            f"continuous actions (steering {steer['low']:g}..{steer['high']:g}°, "
            f"speed {speed['low']:g}..{speed['high']:g} m/s)"
        )
    except (KeyError, TypeError, ValueError):
        return "continuous actions"


@contextmanager
def elapsed_ticker(out: OutputWrapper | None, text: str, every_s: float = 1.0) -> Iterator[None]:
    """``text… 12 s`` kept up to date while the block runs (a long import, say): in place on a
    terminal, a line every 10 s otherwise; silent with ``out=None``."""
    if out is None:
        yield
        return
    tty = bool(out.isatty())
    done = threading.Event()
    started = time.monotonic()

    def tick() -> None:
        last_line = 0.0
        while not done.wait(every_s):
            seconds = time.monotonic() - started
            if tty:
                out.write(f"\r{text}… {seconds:.0f} s", ending="")
                out.flush()
            elif seconds - last_line >= 10:
                out.write(f"{text}… {seconds:.0f} s")
                last_line = seconds

    out.write(f"{text}…", ending="\n" if not tty else "")
    out.flush()
    thread = threading.Thread(target=tick, name="racecraft-ticker", daemon=True)
    thread.start()
    try:
        yield
    finally:
        done.set()
        thread.join(timeout=2)
        if tty:
            out.write(f"\r{text}… done in {time.monotonic() - started:.0f} s")


def owner_and_model(model_id: int, owner: str | None):
    """``(user, model)``: ``owner``'s model ``model_id``, or the model and its owner."""
    with service_errors():
        user = user_by_username(username=owner) if owner else None
        model = model_for_cli(model_id=model_id, user=user)
    return (user or model.owner), model
