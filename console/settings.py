"""Django settings for Racecraft, read from environment variables.

Every variable has a default that runs the whole console on one machine with nothing else
installed: SQLite under var/, an embedded Redis started by ``manage.py up``, objects in a
local folder. Production points DATABASE_URL, REDIS_URL and MINIO_* at real services.
See docs/operator.md ("Configuration") for the table of variables.
"""

from __future__ import annotations

import contextlib
import ipaddress
import os
import re
import secrets
import tempfile
from pathlib import Path

import dj_database_url
from celery.schedules import crontab
from django.core.checks.security.base import SECRET_KEY_INSECURE_PREFIX, SECRET_KEY_MIN_LENGTH
from django.core.exceptions import ImproperlyConfigured

from console.env import envbool, envint, envlist, envstr
from console.redisconf import cache_settings, celery_settings, channel_layers
from training.bucket import DEFAULT_BUCKET, StoreError, check_bucket_name
from training.outbound_allow import parse_allow_entries

BASE_DIR = Path(__file__).resolve().parent.parent
# Runtime state (SQLite file, embedded Redis socket, local object store); git-ignored.
VAR_DIR = Path(envstr("RACECRAFT_VAR_DIR", str(BASE_DIR / "var")))


def _install_secret_key(var_dir: Path) -> str:
    """This installation's own random key, made once in ``var_dir/secret_key`` (mode 0600).

    The first process to start writes it: a temporary file hard-linked into place, so that
    processes starting together (web, workers, test workers) all read the same key."""
    path = var_dir / "secret_key"
    if not path.exists():
        var_dir.mkdir(parents=True, exist_ok=True)
        fd, scratch = tempfile.mkstemp(prefix=".secret_key-", dir=var_dir)  # mode 0600
        try:
            with os.fdopen(fd, "w") as file:
                file.write(secrets.token_urlsafe(64))
            with contextlib.suppress(FileExistsError):  # another process was first
                os.link(scratch, path)
        finally:
            os.unlink(scratch)
    key = path.read_text().strip()
    if len(key) < SECRET_KEY_MIN_LENGTH:
        raise ImproperlyConfigured(f"{path} does not hold a usable key: delete it to make one")
    return key


def _public_key(key: str) -> bool:
    """Unset, or a development key: Django's ``django-insecure-`` ones, the key this console
    used to fall back on (``django-insecure-racecraft-dev-only``, public in its history) among
    them. Shorter keys are `check --deploy`'s warning (security.W009), not refused here."""
    return not key or key.startswith(SECRET_KEY_INSECURE_PREFIX)


# Unset DEBUG means debug mode, for the one-command start on a laptop: `manage.py up` then
# listens on loopback only (console/management/commands/up.py). Without SECRET_KEY, a debug
# console signs with a random key of its own install (var/secret_key), never a public one; a
# production console (DEBUG=0) refuses to start without a key of its operator.
DEBUG = envbool("DEBUG", True)
SECRET_KEY = envstr("SECRET_KEY")
if not DEBUG and _public_key(SECRET_KEY):
    _what = "it is unset" if not SECRET_KEY else "a django-insecure- key is for development"
    raise ImproperlyConfigured(
        f"SECRET_KEY must be set to a long random value when DEBUG=0 ({_what}), e.g. "
        "SECRET_KEY=$(python3 -c 'import secrets; print(secrets.token_urlsafe(64))'), made once "
        "and the same for every process of this console"
    )
if not SECRET_KEY:
    SECRET_KEY = _install_secret_key(VAR_DIR)
# With DEBUG and no hosts, Django accepts localhost, 127.0.0.1 and [::1].
ALLOWED_HOSTS = envlist("ALLOWED_HOSTS")
CSRF_TRUSTED_ORIGINS = envlist("CSRF_TRUSTED_ORIGINS")

INSTALLED_APPS = [
    "daphne",
    "channels",
    "django.contrib.admin",
    "django.contrib.auth",
    "django.contrib.contenttypes",
    "django.contrib.sessions",
    "django.contrib.messages",
    "django.contrib.staticfiles",
    "training",
    "leaderboard",
    "console",
    "csp",
]

MIDDLEWARE = [
    "django.middleware.security.SecurityMiddleware",
    "django.contrib.sessions.middleware.SessionMiddleware",
    "django.middleware.common.CommonMiddleware",
    "django.middleware.csrf.CsrfViewMiddleware",
    "django.contrib.auth.middleware.AuthenticationMiddleware",
    "django.contrib.messages.middleware.MessageMiddleware",
    "django.middleware.clickjacking.XFrameOptionsMiddleware",
    "console.throttle.ThrottleMiddleware",
    "csp.middleware.CSPMiddleware",
    # An unreachable object store or database: a 503 "try again", never a 500.
    "console.middleware.UnavailableMiddleware",
    # Imported tracks from the database into this host's folder (a web host shares no disk).
    "console.middleware.TrackSyncMiddleware",
]

# ---- HTTPS and browser protections. Production (DEBUG=0) runs behind a TLS-terminating proxy
# that sets X-Forwarded-Proto; `manage.py check --deploy` is clean with these defaults.
SECURE_PROXY_SSL_HEADER = ("HTTP_X_FORWARDED_PROTO", "https") if not DEBUG else None
SECURE_SSL_REDIRECT = envbool("SECURE_SSL_REDIRECT", not DEBUG)
SECURE_HSTS_SECONDS = envint("SECURE_HSTS_SECONDS", 0 if DEBUG else 31_536_000, minimum=0)
SECURE_HSTS_INCLUDE_SUBDOMAINS = envbool("SECURE_HSTS_INCLUDE_SUBDOMAINS", not DEBUG)
SECURE_HSTS_PRELOAD = envbool("SECURE_HSTS_PRELOAD", False)
# Submitting a domain to the browsers' HSTS preload list is the operator's decision (it is
# hard to undo), so `check --deploy` does not nag about it; SECURE_HSTS_PRELOAD=1 opts in.
SILENCED_SYSTEM_CHECKS = ["security.W021"]
SESSION_COOKIE_SECURE = not DEBUG
CSRF_COOKIE_SECURE = not DEBUG
X_FRAME_OPTIONS = "DENY"
# Content Security Policy (django-csp), in force in development too so tests see violations:
# scripts only from our own files (no inline code), websockets to ourselves.
CONTENT_SECURITY_POLICY = {
    "DIRECTIVES": {
        "default-src": ["'self'"],
        "script-src": ["'self'"],
        "style-src": ["'self'", "'unsafe-inline'"],
        "img-src": ["'self'", "data:", "blob:"],
        "media-src": ["'self'", "blob:"],
        "connect-src": ["'self'", "ws:", "wss:"],
        "font-src": ["'self'"],
        "object-src": ["'none'"],
        "base-uri": ["'self'"],
        "form-action": ["'self'"],
        "frame-ancestors": ["'none'"],
    }
}

ROOT_URLCONF = "console.urls"
ASGI_APPLICATION = "console.asgi.application"

TEMPLATES = [
    {
        "BACKEND": "django.template.backends.django.DjangoTemplates",
        "DIRS": [BASE_DIR / "templates"],
        "APP_DIRS": True,
        "OPTIONS": {
            "context_processors": [
                "django.template.context_processors.request",
                "django.contrib.auth.context_processors.auth",
                "django.contrib.messages.context_processors.messages",
                "console.context_processors.sandbox_warning",
            ],
        },
    },
]

# Database: SQLite under var/ unless DATABASE_URL says otherwise.
_database_url = envstr("DATABASE_URL")
if _database_url:
    try:
        DATABASES = {
            "default": dj_database_url.parse(
                _database_url, conn_max_age=envint("DB_CONN_MAX_AGE", 0, minimum=0)
            )
        }
    except ValueError as exc:
        raise ImproperlyConfigured(f"DATABASE_URL is not a database URL: {exc}") from None
else:
    VAR_DIR.mkdir(parents=True, exist_ok=True)
    DATABASES = {
        "default": {
            "ENGINE": "django.db.backends.sqlite3",
            "NAME": VAR_DIR / "db.sqlite3",
        }
    }
if DATABASES["default"]["ENGINE"] == "django.db.backends.sqlite3":
    # Tests on SQLite use a file, so that a real Celery worker process can share it.
    DATABASES["default"].setdefault("TEST", {}).setdefault("NAME", str(VAR_DIR / "test-db.sqlite3"))
    # The web server and the Celery worker write at the same time: WAL lets readers go on
    # while one writes, IMMEDIATE takes the write lock up front instead of failing mid-way.
    DATABASES["default"].setdefault("OPTIONS", {}).update(
        {
            "transaction_mode": "IMMEDIATE",
            "timeout": 20,
            "init_command": "PRAGMA journal_mode=WAL; PRAGMA synchronous=NORMAL;",
        }
    )
DEFAULT_AUTO_FIELD = "django.db.models.BigAutoField"

AUTH_PASSWORD_VALIDATORS = [
    {"NAME": "django.contrib.auth.password_validation.UserAttributeSimilarityValidator"},
    {"NAME": "django.contrib.auth.password_validation.MinimumLengthValidator"},
    {"NAME": "django.contrib.auth.password_validation.CommonPasswordValidator"},
    {"NAME": "django.contrib.auth.password_validation.NumericPasswordValidator"},
]
LOGIN_URL = "/accounts/login/"
LOGIN_REDIRECT_URL = "/"

LANGUAGE_CODE = "en-us"
TIME_ZONE = "UTC"
USE_I18N = True
USE_TZ = True

STATIC_URL = "static/"
STATICFILES_DIRS = [BASE_DIR / "static"]
STATIC_ROOT = BASE_DIR / "staticfiles"
# The ASGI app serves static files itself (no collectstatic needed); turn it off when a
# reverse proxy serves STATIC_ROOT.
SERVE_STATIC = envbool("SERVE_STATIC", True)

# Redis: Celery broker and results, Channels layer, live state. Unset means the embedded
# Redis that `manage.py up` starts on a unix socket under var/.
EMBEDDED_REDIS_SOCKET = VAR_DIR / "redis" / "redis.sock"
REDIS_URL = envstr("REDIS_URL") or f"unix://{EMBEDDED_REDIS_SOCKET}?db=0"
# Prepended to every key we write, so several installs (or test runs) can share one Redis.
REDIS_PREFIX = envstr("REDIS_PREFIX")

CHANNEL_LAYERS = channel_layers(REDIS_URL, REDIS_PREFIX)
# The throttles' counts (django-ratelimit) and any cached value: one Redis for every process.
CACHES = cache_settings(REDIS_URL, REDIS_PREFIX)

# Celery (read by console/celery.py with the CELERY_ namespace).
_celery = celery_settings(REDIS_URL, REDIS_PREFIX)
CELERY_BROKER_URL = _celery["CELERY_BROKER_URL"]
CELERY_RESULT_BACKEND = _celery["CELERY_RESULT_BACKEND"]
CELERY_BROKER_TRANSPORT_OPTIONS = _celery["CELERY_BROKER_TRANSPORT_OPTIONS"]
CELERY_RESULT_BACKEND_TRANSPORT_OPTIONS = _celery["CELERY_RESULT_BACKEND_TRANSPORT_OPTIONS"]
CELERY_BROKER_CONNECTION_RETRY_ON_STARTUP = True
CELERY_TASK_DEFAULT_QUEUE = "default"
CELERY_TASK_TRACK_STARTED = True
CELERY_TASK_SERIALIZER = "json"
CELERY_RESULT_SERIALIZER = "json"
CELERY_ACCEPT_CONTENT = ["json"]
CELERY_RESULT_EXPIRES = 24 * 3600
# Jobs are long: a worker takes one task at a time, so others stay free for idle workers.
CELERY_WORKER_PREFETCH_MULTIPLIER = 1
# Job tasks are acknowledged late and given back when their worker process dies (set on the
# tasks, training/tasks.py). An unacknowledged task is handed out again after the visibility
# timeout: longer than the longest job, so a running job's task is not duplicated (if it were,
# the job's claim, a compare-and-set, would skip it).
# Time limits per task type (console/celery.py): jobs may run as long as the longest job allowed
# (MAX_MINUTES, 24 h) plus set-up and export; evaluations and quick tasks much less.
RACECRAFT_JOB_TIME_LIMIT_S = envint("RACECRAFT_JOB_TIME_LIMIT_S", 1440 * 60 + 1800, minimum=60)
RACECRAFT_EVALUATION_TIME_LIMIT_S = envint("RACECRAFT_EVALUATION_TIME_LIMIT_S", 1800, minimum=60)
RACECRAFT_QUICK_TASK_TIME_LIMIT_S = envint("RACECRAFT_QUICK_TASK_TIME_LIMIT_S", 300, minimum=10)
for _options in (CELERY_BROKER_TRANSPORT_OPTIONS,):
    _options.setdefault("visibility_timeout", RACECRAFT_JOB_TIME_LIMIT_S + 3600)
CELERY_WORKER_CONCURRENCY = envint("CELERY_WORKER_CONCURRENCY", 2, minimum=1)
# `manage.py up` runs one worker per kind of work (console/launcher.py): training
# (CELERY_WORKER_CONCURRENCY processes), evaluation, quick tasks (the reaper, the league), and
# simulation when RACECRAFT_REMOTE_ROLLOUT_SLOTS > 0; job workers at this added niceness.
RACECRAFT_EVALUATION_CONCURRENCY = envint("RACECRAFT_EVALUATION_CONCURRENCY", 1, minimum=1)
RACECRAFT_QUICK_CONCURRENCY = envint("RACECRAFT_QUICK_CONCURRENCY", 2, minimum=1)
# Processes of the worker for what users' pages wait for (queue `interactive`: reward
# validations and replays, model imports, car exports), apart from the reaper's.
RACECRAFT_INTERACTIVE_CONCURRENCY = envint("RACECRAFT_INTERACTIVE_CONCURRENCY", 2, minimum=1)
RACECRAFT_WORKER_NICE = envint("RACECRAFT_WORKER_NICE", 10, minimum=0)
# Periodic tasks (celery beat): the league's month-end promotion (daily, idempotent: catches
# up a missed night) and its safety net for results whose signal was missed.
CELERY_BEAT_SCHEDULE = {
    "league-promote-divisions": {
        "task": "leaderboard.tasks.promote_divisions",
        "schedule": crontab(minute=10, hour=0),
    },
    "league-reconcile-submissions": {
        "task": "leaderboard.tasks.reconcile_submissions",
        "schedule": 60.0,
    },
    "training-reap-orphans": {
        "task": "training.tasks.reap_orphans",
        "schedule": 120.0,
    },
    "training-prune-uploads": {
        "task": "training.tasks.prune_uploads",
        "schedule": 3600.0,
    },
}

# Object store: MinIO when MINIO_ENDPOINT is set, else a local folder (STORE_DIR).
MINIO_ENDPOINT = envstr("MINIO_ENDPOINT")
MINIO_ACCESS_KEY = envstr("MINIO_ACCESS_KEY")
MINIO_SECRET_KEY = envstr("MINIO_SECRET_KEY")
MINIO_SECURE = envbool("MINIO_SECURE", False)
try:
    MINIO_BUCKET = check_bucket_name(envstr("MINIO_BUCKET", DEFAULT_BUCKET))
except StoreError as exc:
    raise ImproperlyConfigured(f"MINIO_BUCKET: {exc}") from None
if MINIO_ENDPOINT and not (MINIO_ACCESS_KEY and MINIO_SECRET_KEY):
    raise ImproperlyConfigured("MINIO_ENDPOINT is set: MINIO_ACCESS_KEY and MINIO_SECRET_KEY too")
STORE_DIR = Path(envstr("STORE_DIR", str(VAR_DIR / "store")))
# Transient store errors (unreachable, 5xx) are retried with backoff for this long: briefly in
# the web server (then "storage unavailable, try again"), long in workers (a checkpoint write
# outlives an outage).
RACECRAFT_STORE_RETRY_S = envint("RACECRAFT_STORE_RETRY_S", 3, minimum=0)
RACECRAFT_STORE_WORKER_RETRY_S = envint("RACECRAFT_STORE_WORKER_RETRY_S", 180, minimum=0)

# Training: rollouts on this machine (0) or on that many `-Q simulation` workers elsewhere.
RACECRAFT_REMOTE_ROLLOUT_SLOTS = envint("RACECRAFT_REMOTE_ROLLOUT_SLOTS", 0, minimum=0)
# The trainer's torch device: auto (the GPU when the training worker has one, else the CPU),
# cpu, cuda, cuda:<n>, mps. Checked for spelling here; for the GPU itself on the worker.
RACECRAFT_TORCH_DEVICE = envstr("RACECRAFT_TORCH_DEVICE", "auto").strip().lower()
if not re.fullmatch(r"auto|cpu|cuda(:\d+)?|mps|xpu(:\d+)?", RACECRAFT_TORCH_DEVICE):
    raise ImproperlyConfigured(
        f"RACECRAFT_TORCH_DEVICE={RACECRAFT_TORCH_DEVICE!r}: use auto, cpu, cuda, cuda:<n> or mps"
    )
# "streams": simulation workers own their episodes and stream them through Redis (issue 14);
# "lockstep": the trainer steps the envs.
RACECRAFT_SIMULATION = envstr("RACECRAFT_SIMULATION", "lockstep")
if RACECRAFT_SIMULATION not in ("streams", "lockstep"):
    raise ImproperlyConfigured("RACECRAFT_SIMULATION must be streams or lockstep")
RACECRAFT_MAX_MODELS_PER_USER = envint("RACECRAFT_MAX_MODELS_PER_USER", 50, minimum=1)
RACECRAFT_MAX_ACTIVE_JOBS_PER_USER = envint("RACECRAFT_MAX_ACTIVE_JOBS_PER_USER", 2, minimum=1)
# A job whose worker died is queued again (training resumes from its last checkpoint) until
# it has been claimed this many times; then it fails.
RACECRAFT_JOB_MAX_ATTEMPTS = envint("RACECRAFT_JOB_MAX_ATTEMPTS", 3, minimum=1)

# Track files a user imported (e.g. DeepRacer's .npy files, which we never commit).
RACECRAFT_TRACKS_DIR = Path(envstr("RACECRAFT_TRACKS_DIR", str(VAR_DIR / "tracks")))
# A web process brings that folder up to date from the database at most this often (seconds;
# 0: never): imported tracks are recorded in the database, and a web host shares no disk.
RACECRAFT_TRACKS_SYNC_S = envint("RACECRAFT_TRACKS_SYNC_S", 30, minimum=0)
# Reward code runs only where every isolation protection is in force (training/sandbox/
# requirements.py); 1 accepts weaker isolation and shows a warning on every page.
RACECRAFT_ALLOW_WEAK_SANDBOX = envbool("RACECRAFT_ALLOW_WEAK_SANDBOX", False)
# Reward validations run as Celery tasks; per user: at once, and started per minute.
RACECRAFT_VALIDATIONS_PER_USER = envint("RACECRAFT_VALIDATIONS_PER_USER", 2, minimum=1)
RACECRAFT_VALIDATIONS_PER_MINUTE = envint("RACECRAFT_VALIDATIONS_PER_MINUTE", 10, minimum=1)
# Model imports and car exports (Celery tasks on the `interactive` queue) a user may have
# queued or running at once.
RACECRAFT_BACKGROUND_TASKS_PER_USER = envint("RACECRAFT_BACKGROUND_TASKS_PER_USER", 2, minimum=1)
# Sign-up and log-in POSTs per address (log-in also per user name): django-ratelimit rates.
RACECRAFT_LOGIN_RATE = envstr("RACECRAFT_LOGIN_RATE", "10/m")
RACECRAFT_SIGNUP_RATE = envstr("RACECRAFT_SIGNUP_RATE", "5/h")
# Race layout pictures (/tracks/<id>/race.png, each drawn on request) per address.
RACECRAFT_PREVIEW_RATE = envstr("RACECRAFT_PREVIEW_RATE", "300/m")
# Imports from a DeepRacer-for-Cloud bucket (each reads a remote server) per user.
RACECRAFT_BUCKET_IMPORT_RATE = envstr("RACECRAFT_BUCKET_IMPORT_RATE", "20/h")
for _name in ("RACECRAFT_LOGIN_RATE", "RACECRAFT_SIGNUP_RATE", "RACECRAFT_PREVIEW_RATE",
              "RACECRAFT_BUCKET_IMPORT_RATE"):  # fmt: skip
    if not re.fullmatch(r"\d+/\d*[smhd]", globals()[_name]):
        raise ImproperlyConfigured(f"{_name}={globals()[_name]!r} is not a rate like 10/m")
# Rates count per client address. Behind a reverse proxy every request comes from the proxy's
# address: list the proxies here (addresses or networks, comma-separated) and, for requests
# that come from one of them, the right-most address of X-Forwarded-For that is not a listed
# proxy is the client's (console/throttle.py client_ip). From any other address the header is
# ignored, so a client cannot pick its own bucket.
RACECRAFT_TRUSTED_PROXIES = envlist("RACECRAFT_TRUSTED_PROXIES")
for _proxy in RACECRAFT_TRUSTED_PROXIES:
    try:
        ipaddress.ip_network(_proxy, strict=False)
    except ValueError:
        raise ImproperlyConfigured(
            f"RACECRAFT_TRUSTED_PROXIES: {_proxy!r} is not an IP address or network"
        ) from None
RATELIMIT_IP_META_KEY = "console.throttle.client_ip"
# Requests the server sends to an address a user typed (the bucket import today) reach only
# public addresses: never loopback, the LAN, link-local (a cloud's 169.254.169.254 metadata,
# which holds the instance's credentials) and the like, else any racer could read the server's
# internal services (training/storage/outbound.py). List here, comma-separated, the host names,
# addresses or networks that may be reached although they are not public: e.g. the LAN MinIO
# of a DeepRacer-for-Cloud install (minio.lan, 192.168.1.20, 10.0.0.0/24, localhost). Every
# racer may then reach them: list only servers meant for that. Empty by default.
RACECRAFT_OUTBOUND_ALLOW = envlist("RACECRAFT_OUTBOUND_ALLOW")
try:  # the guarded client's own parser (training/outbound_allow.py), so both agree
    parse_allow_entries(RACECRAFT_OUTBOUND_ALLOW)
except ValueError as _exc:
    raise ImproperlyConfigured(f"RACECRAFT_OUTBOUND_ALLOW: {_exc}") from None

LOGGING = {
    "version": 1,
    "disable_existing_loggers": False,
    "handlers": {"console": {"class": "logging.StreamHandler"}},
    "root": {"handlers": ["console"], "level": envstr("LOG_LEVEL", "INFO").upper()},
    "loggers": {"django.db.backends": {"level": "INFO"}},
}
