"""Business rules for models and jobs: what the web console, the command line and the Celery
tasks may ask for. Every function is keyword-only, named ``<entity>_<action>``, and raises
:class:`ServiceError` (or :class:`RewardRejected`, which carries structured reward errors) with
a message a user can act on. Side effects on other processes start only after the commit.

- :mod:`~training.services.models`: create, clone, delete a model, change its reward function.
- :mod:`~training.services.model_imports`: a model from an uploaded archive.
- :mod:`~training.services.bucket_imports`: a model straight from a DeepRacer-for-Cloud bucket.
- :mod:`~training.services.model_files`: what a model's folder in the store says about it;
  a store failure as a user reads it.
- :mod:`~training.services.jobs`: the one state machine of training and evaluation jobs.
- :mod:`~training.services.job_queue`: fair dispatch, which queued job a free slot runs next.
- :mod:`~training.services.records`: what a running job records besides its status (a
  checkpoint exists, where an evaluation's logs are).
- :mod:`~training.services.checks`: tracks, configurations, reward functions, names, quotas.
- :mod:`~training.services.downloads`: what a user downloads.
- :mod:`~training.services.rewards`: reward validations on a worker, and the passes that let
  the web save a reward function without running it.
- :mod:`~training.services.background`: model imports and car exports on a worker.
- :mod:`~training.services.tracks`: importing a track file from the console.
- :mod:`~training.services.trackfiles`: imported tracks by content, from the database to each
  machine's folder.

Reads go through :mod:`training.selectors`.
"""

from training.errors import RewardRejected, ServiceError
from training.services.bucket_imports import model_import_from_bucket
from training.services.checks import (
    MAX_MINUTES,
    MIN_MINUTES,
    ModelSpec,
    check_extra_tracks,
    check_model_spec,
    check_name,
    check_race_type,
    check_reward,
    check_track,
    track_catalog,
)
from training.services.downloads import deepracer_on_aws_refusal
from training.services.job_queue import jobs_ahead
from training.services.jobs import (
    evaluation_start,
    job_begin,
    job_claim,
    job_complete,
    job_fail,
    job_heartbeat,
    job_resumed_from,
    job_stop,
    job_stop_requested,
    jobs_fail_for_worker,
    jobs_reap_orphans,
    jobs_requeue_for_worker,
    model_settle,
    training_start,
)
from training.services.model_files import model_freeze, model_metadata
from training.services.model_imports import model_import
from training.services.models import model_clone, model_create, model_delete, model_update_reward
from training.services.races import RacePlan, race_plan
from training.services.racing import (
    RACE_DEFAULTS,
    SUPPORTED_RACE_TYPES,
    parse_object_positions,
    race_config,
    race_settings,
    sensor_advice,
)
from training.services.records import evaluation_record_logs, model_mark_checkpoint
from training.services.trackfiles import (
    track_hashes,
    tracks_check_recorded,
    tracks_sync,
    tracks_sync_for,
)
from training.services.tracks import (
    TrackCheck,
    default_track_id,
    track_add,
    track_check,
    track_import,
)

__all__ = [
    "MAX_MINUTES",
    "MIN_MINUTES",
    "ModelSpec",
    "RACE_DEFAULTS",
    "RacePlan",
    "RewardRejected",
    "SUPPORTED_RACE_TYPES",
    "ServiceError",
    "TrackCheck",
    "check_extra_tracks",
    "check_model_spec",
    "check_name",
    "check_race_type",
    "check_reward",
    "deepracer_on_aws_refusal",
    "check_track",
    "default_track_id",
    "evaluation_record_logs",
    "evaluation_start",
    "job_begin",
    "job_claim",
    "jobs_ahead",
    "job_complete",
    "job_fail",
    "job_heartbeat",
    "job_resumed_from",
    "job_stop",
    "job_stop_requested",
    "jobs_fail_for_worker",
    "jobs_reap_orphans",
    "jobs_requeue_for_worker",
    "model_clone",
    "model_create",
    "model_delete",
    "model_import",
    "model_import_from_bucket",
    "model_mark_checkpoint",
    "model_freeze",
    "model_metadata",
    "model_settle",
    "model_update_reward",
    "parse_object_positions",
    "race_config",
    "race_plan",
    "race_settings",
    "sensor_advice",
    "track_add",
    "track_catalog",
    "track_check",
    "track_hashes",
    "track_import",
    "tracks_check_recorded",
    "tracks_sync",
    "tracks_sync_for",
    "training_start",
]
