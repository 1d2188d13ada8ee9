"""Settings come from environment variables; bad values stop the start with a clear error."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from django.core.exceptions import ImproperlyConfigured

from console.env import envbool, envint, envlist, envstr
from console.redisconf import celery_settings, celery_url, channel_layers

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize(
    ("raw", "expected"),
    [("1", True), ("TRUE", True), ("yes", True), ("on", True), ("0", False), ("False", False)],
)
def test_envbool_reads_common_spellings(
    monkeypatch: pytest.MonkeyPatch, raw: str, expected: bool
) -> None:
    monkeypatch.setenv("RC_FLAG", raw)
    assert envbool("RC_FLAG", not expected) is expected


def test_envbool_default_when_unset_or_empty(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("RC_FLAG", raising=False)
    assert envbool("RC_FLAG", True) is True
    monkeypatch.setenv("RC_FLAG", "  ")
    assert envbool("RC_FLAG", False) is False


def test_envbool_rejects_other_values(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("RC_FLAG", "maybe")
    with pytest.raises(ImproperlyConfigured, match="RC_FLAG='maybe' is not a boolean"):
        envbool("RC_FLAG", False)


def test_envint(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("RC_NUM", raising=False)
    assert envint("RC_NUM", 7) == 7
    monkeypatch.setenv("RC_NUM", "42")
    assert envint("RC_NUM", 7) == 42
    monkeypatch.setenv("RC_NUM", "4.5")
    with pytest.raises(ImproperlyConfigured, match="not an integer"):
        envint("RC_NUM", 7)
    monkeypatch.setenv("RC_NUM", "0")
    with pytest.raises(ImproperlyConfigured, match="below the minimum 1"):
        envint("RC_NUM", 7, minimum=1)


def test_envstr_and_envlist(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("RC_TEXT", "  hello ")
    assert envstr("RC_TEXT") == "hello"
    monkeypatch.delenv("RC_TEXT")
    assert envstr("RC_TEXT", "fallback") == "fallback"
    monkeypatch.setenv("RC_HOSTS", "a.example, b.example,,")
    assert envlist("RC_HOSTS") == ["a.example", "b.example"]


def test_unix_socket_url_is_translated_for_celery() -> None:
    assert celery_url("unix:///tmp/r.sock?db=3") == "redis+socket:///tmp/r.sock?virtual_host=3"
    assert celery_url("unix:///tmp/r.sock") == "redis+socket:///tmp/r.sock?virtual_host=0"
    assert celery_url("redis://127.0.0.1:6379/15") == "redis://127.0.0.1:6379/15"


def test_redis_prefix_reaches_every_client() -> None:
    layers = channel_layers("redis://h:6379/1", "p:")
    assert layers["default"]["CONFIG"] == {"hosts": ["redis://h:6379/1"], "prefix": "p:asgi"}
    celery = celery_settings("redis://h:6379/1", "p:")
    assert celery["CELERY_BROKER_TRANSPORT_OPTIONS"] == {"global_keyprefix": "p:"}
    assert celery["CELERY_RESULT_BACKEND_TRANSPORT_OPTIONS"] == {"global_keyprefix": "p:"}
    assert celery_settings("redis://h:6379/1", "")["CELERY_BROKER_TRANSPORT_OPTIONS"] == {}


SUMMARY = (
    "import console.settings as s;"
    "print(s.DATABASES['default']['ENGINE'], s.MINIO_BUCKET, s.REDIS_URL, s.DEBUG)"
)


def _load_settings(
    tmp_path: Path, code: str = SUMMARY, **env: str
) -> subprocess.CompletedProcess[str]:
    """Import console.settings in a fresh interpreter with exactly ``env`` set."""
    clean = {k: v for k, v in os.environ.items() if k in ("PATH", "HOME", "LANG")}
    clean |= {"RACECRAFT_VAR_DIR": str(tmp_path / "var"), **env}
    return subprocess.run(
        [sys.executable, "-c", code],
        cwd=REPO,
        env=clean,
        capture_output=True,
        text=True,
        timeout=60,
    )


def test_defaults_need_no_environment(tmp_path: Path) -> None:
    result = _load_settings(tmp_path)
    assert result.returncode == 0, result.stderr
    engine, bucket, redis_url, debug = result.stdout.split()
    assert engine == "django.db.backends.sqlite3"
    assert bucket == "deepracer-models"
    assert redis_url == f"unix://{tmp_path}/var/redis/redis.sock?db=0"
    assert debug == "True"
    assert (tmp_path / "var").is_dir()


@pytest.mark.parametrize(
    ("env", "message"),
    [
        ({"DEBUG": "perhaps"}, "DEBUG='perhaps' is not a boolean"),
        ({"DEBUG": "0"}, "SECRET_KEY must be set to a long random value when DEBUG=0 (it is"),
        # The old public development key, or any of Django's django-insecure- keys.
        (
            {"DEBUG": "0", "SECRET_KEY": "django-insecure-racecraft-dev-only"},
            "SECRET_KEY must be set to a long random value when DEBUG=0 (a django-insecure- key",
        ),
        ({"DEBUG": "no", "SECRET_KEY": "django-insecure-" + "x7Qp" * 20}, "SECRET_KEY must be"),
        ({"RACECRAFT_TRUSTED_PROXIES": "10.0.0.1, nginx"}, "'nginx' is not an IP address"),
        ({"MINIO_BUCKET": "models"}, "MINIO_BUCKET: bucket 'models' must start with 'deepracer'"),
        ({"MINIO_BUCKET": "deepracer_x"}, "MINIO_BUCKET: bucket 'deepracer_x' is not a valid"),
        ({"MINIO_SECURE": "2"}, "MINIO_SECURE='2' is not a boolean"),
        ({"MINIO_ENDPOINT": "minio:9000"}, "MINIO_ACCESS_KEY and MINIO_SECRET_KEY"),
        ({"CELERY_WORKER_CONCURRENCY": "many"}, "not an integer"),
        ({"DATABASE_URL": "nosuchdb://x/y"}, "DATABASE_URL"),
        ({"RACECRAFT_TORCH_DEVICE": "gpu"}, "RACECRAFT_TORCH_DEVICE='gpu': use auto, cpu, cuda"),
    ],
)
def test_bad_environment_raises_improperly_configured(
    tmp_path: Path, env: dict[str, str], message: str
) -> None:
    result = _load_settings(tmp_path, **env)
    assert result.returncode != 0
    assert "ImproperlyConfigured" in result.stderr
    assert message in result.stderr


def test_the_torch_device_is_auto_unless_set(tmp_path: Path) -> None:
    code = "import console.settings as s; print(s.RACECRAFT_TORCH_DEVICE)"
    for env, expected in (({}, "auto"), ({"RACECRAFT_TORCH_DEVICE": "CUDA:1"}, "cuda:1")):
        clean = {k: v for k, v in os.environ.items() if k in ("PATH", "HOME", "LANG")}
        clean |= {"RACECRAFT_VAR_DIR": str(tmp_path / "var"), **env}
        result = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=clean,
                                capture_output=True, text=True, timeout=60)  # fmt: skip
        assert result.returncode == 0, result.stderr
        assert result.stdout.split() == [expected]


def test_database_url_selects_postgresql(tmp_path: Path) -> None:
    result = _load_settings(tmp_path, DATABASE_URL="postgres://postgres@127.0.0.1:5432/test")
    assert result.returncode == 0, result.stderr
    assert result.stdout.split()[0] == "django.db.backends.postgresql"


KEY = "import console.settings as s; print(s.SECRET_KEY)"


def test_a_debug_console_signs_with_its_own_install_key(tmp_path: Path) -> None:
    """Nothing configured: a random key made once in var/secret_key (readable by its owner
    only), the same for every later process of this install, another for another install;
    never the public development key."""
    first = _load_settings(tmp_path, KEY)
    assert first.returncode == 0, first.stderr
    key = first.stdout.strip()
    stored = tmp_path / "var" / "secret_key"
    assert stored.read_text().strip() == key and len(key) >= 50
    assert stored.stat().st_mode & 0o777 == 0o600
    assert not key.startswith("django-insecure")
    assert _load_settings(tmp_path, KEY).stdout.strip() == key
    other = _load_settings(tmp_path / "other", KEY)
    assert other.returncode == 0 and other.stdout.strip() not in ("", key)


def test_a_production_console_uses_only_its_operators_key(tmp_path: Path) -> None:
    strong = "k" + "".join(chr(ord("a") + i % 26) for i in range(63))
    result = _load_settings(tmp_path, KEY, DEBUG="0", SECRET_KEY=strong)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == strong
    assert not (tmp_path / "var" / "secret_key").exists()  # no key of its own was made


def test_trusted_proxies_default_to_none(tmp_path: Path) -> None:
    code = "import console.settings as s; print(s.RACECRAFT_TRUSTED_PROXIES)"
    assert _load_settings(tmp_path, code).stdout.strip() == "[]"
    listed = _load_settings(tmp_path, code, RACECRAFT_TRUSTED_PROXIES="10.0.0.2, 172.16.0.0/12")
    assert listed.stdout.strip() == "['10.0.0.2', '172.16.0.0/12']"
