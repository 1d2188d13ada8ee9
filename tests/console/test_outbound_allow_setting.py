"""RACECRAFT_OUTBOUND_ALLOW: settings check it with the guarded client's own parser
(training/outbound_allow.py), so what starts is what the client understands, and a bad entry
stops the start with the client's message."""

from __future__ import annotations

import ipaddress
from pathlib import Path

import pytest

from tests.console.test_env_settings import _load_settings
from training.outbound_allow import parse_allow_entries
from training.storage.outbound import AllowList

SHOW = "import console.settings as s; print(s.RACECRAFT_OUTBOUND_ALLOW)"


def test_settings_accept_what_the_client_parses(tmp_path: Path) -> None:
    value = "MinIO.lan., 10.0.0.0/24, 192.168.1.20, [::1]"
    result = _load_settings(tmp_path, SHOW, RACECRAFT_OUTBOUND_ALLOW=value)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == repr(["MinIO.lan.", "10.0.0.0/24", "192.168.1.20", "[::1]"])
    allow = AllowList.parse(value.split(","))
    assert allow.hosts == {"minio.lan"}
    assert allow.allows("x", ipaddress.ip_address("10.0.0.7"))


@pytest.mark.parametrize("bad", ["http://minio.lan/", "minio lan", "-minio", "a/b"])
def test_settings_refuse_with_the_client_message(tmp_path: Path, bad: str) -> None:
    with pytest.raises(ValueError) as refused:
        parse_allow_entries([bad])
    message = str(refused.value)
    assert message == f"{bad!r} is not a host name, an IP address or a network"
    result = _load_settings(tmp_path, SHOW, RACECRAFT_OUTBOUND_ALLOW=f"minio.lan, {bad}")
    assert result.returncode != 0
    assert "ImproperlyConfigured" in result.stderr
    assert f"RACECRAFT_OUTBOUND_ALLOW: {message}" in result.stderr


def test_one_parser_for_both() -> None:
    entries = ["MinIO.lan.", "10.0.0.0/24", " ", "::1"]
    hosts, networks = parse_allow_entries(entries)
    allow = AllowList.parse(entries)
    assert (allow.hosts, allow.networks) == (hosts, networks)
    assert hosts == frozenset({"minio.lan"})
    assert [str(n) for n in networks] == ["10.0.0.0/24", "::1/128"]
