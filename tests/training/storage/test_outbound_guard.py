"""The guarded outbound client (training/storage/outbound.py) and the bucket import through
it, against a real hostile HTTP server on loopback (tests/training/storage/hostile_bucket.py):
whatever the server does, the import is refused with the one sentence, within the deadline,
having read at most the bound, and nothing the server sent reaches the user or the log. Only
name resolution is faked (``socket.getaddrinfo`` for made-up names); connections are real."""

from __future__ import annotations

import ipaddress
import logging
import socket
import time
from collections.abc import Iterator

import pytest

from tests.training.storage.hostile_bucket import BUCKET, HUGE_BYTES, PREFIX, hostile_server
from training.services import ServiceError, bucket_imports
from training.storage.foreign_s3 import LISTING_BODY_BYTES
from training.storage.outbound import (
    AllowList,
    Endpoint,
    OutboundError,
    OutboundPolicy,
    OutboundSession,
    address_is_public,
)

DEADLINE_S = 3.0
"""The import's deadline in these tests (seconds); the trickle would take 20 s per byte."""


# ------------------------------------------------------------------------- the addresses
@pytest.mark.parametrize(
    "address",
    ["127.0.0.1", "127.255.0.9", "::1", "10.1.2.3", "172.16.0.1", "172.31.255.254",
     "192.168.1.20", "169.254.169.254", "fe80::1", "fc00::1", "fd12:3456::1",
     "::ffff:127.0.0.1", "::ffff:169.254.169.254", "0.0.0.0", "::", "224.0.0.1", "ff02::1",
     "240.0.0.1", "255.255.255.255", "100.64.0.1", "100.127.255.254", "2002:7f00:1::1",
     "64:ff9b::a9fe:a9fe", "192.0.2.1", "198.18.0.1"],
)  # fmt: skip
def test_an_address_that_is_not_public_is_refused(address) -> None:
    assert not address_is_public(address)
    assert not address_is_public(ipaddress.ip_address(address))


@pytest.mark.parametrize("address", ["93.184.216.34", "8.8.8.8", "2606:4700::1111",
                                     "100.128.0.1", "172.32.0.1", "::ffff:8.8.8.8"])  # fmt: skip
def test_a_public_address_is_allowed(address) -> None:
    assert address_is_public(address)


def test_the_allow_list_lets_named_hosts_and_networks_through() -> None:
    allow = AllowList.parse(["MinIO.lan.", "10.0.0.0/24", "192.168.1.20", "[::1]", " "])
    ip = ipaddress.ip_address
    assert allow.allows("minio.lan", ip("10.9.9.9"))  # the name, whatever it resolves to
    assert allow.allows("other.lan", ip("10.0.0.5"))  # the network
    assert allow.allows("other.lan", ip("::ffff:10.0.0.5"))  # the same, mapped
    assert allow.allows("192.168.1.20", ip("192.168.1.20"))
    assert allow.allows("localhost", ip("::1"))
    assert not allow.allows("other.lan", ip("10.0.1.5"))
    assert not allow.allows("other.lan", ip("127.0.0.1"))
    assert not AllowList().allows("localhost", ip("127.0.0.1"))  # empty by default
    with pytest.raises(ValueError, match="not a host name"):
        AllowList.parse(["http://minio.lan/"])


@pytest.mark.parametrize(
    "text, secure, parsed",
    [("minio:9000", False, ("minio", 9000, False)), ("https://s3.example.com", False,
      ("s3.example.com", 443, True)), ("http://[::1]:9000/", True, ("::1", 9000, False)),
     ("10.0.0.5", False, ("10.0.0.5", 80, False))],
)  # fmt: skip
def test_an_endpoint_is_host_and_port(text, secure, parsed) -> None:
    endpoint = Endpoint.parse(text, secure=secure)
    assert (endpoint.host, endpoint.port, endpoint.secure) == parsed


@pytest.mark.parametrize("text", ["", "a:b", "a:99999", "a/b", "user@host:1", "a b:1", "[::1"])
def test_a_bad_endpoint_is_refused(text) -> None:
    with pytest.raises(ValueError):
        Endpoint.parse(text, secure=False)


# ------------------------------------------------------------------------- names, faked
@pytest.fixture
def names(monkeypatch) -> dict[str, list[str]]:
    """Made-up host names → the addresses ``getaddrinfo`` answers for them (in order); every
    other name and every address literal resolves as usual. Lookups are counted under
    ``names["#" + name]``."""
    table: dict[str, list[str]] = {}
    real = socket.getaddrinfo

    def fake(host, port, *args, **kwargs):
        if isinstance(host, str) and host in table:
            table.setdefault(f"#{host}", []).append("looked up")
            return [
                (socket.AF_INET6 if ":" in a else socket.AF_INET, socket.SOCK_STREAM, 6, "",
                 (a, port))
                for a in table[host]
            ]  # fmt: skip
        return real(host, port, *args, **kwargs)

    monkeypatch.setattr(socket, "getaddrinfo", fake)
    return table


@pytest.fixture
def server() -> Iterator:
    """The hostile server, plus an "internal service" it redirects to (which must never be
    asked anything)."""
    with hostile_server() as internal, hostile_server() as hostile:
        hostile.internal_url = f"http://{internal.endpoint}"
        hostile.internal = internal
        yield hostile


@pytest.fixture
def short_import(settings, monkeypatch) -> None:
    """Imports may reach loopback (where the hostile server is), under a short deadline."""
    settings.RACECRAFT_OUTBOUND_ALLOW = ["127.0.0.1"]
    monkeypatch.setattr(bucket_imports, "BUCKET_DEADLINE_S", DEADLINE_S)


def import_from(endpoint: str) -> ServiceError:
    with pytest.raises(ServiceError) as refused:
        bucket_imports.bucket_model_archive(endpoint=endpoint, bucket=BUCKET, prefix=PREFIX,
                                            access_key="AKIAHOSTILE", secret_key="s3cr3t",
                                            secure=False)  # fmt: skip
    return refused.value


def assert_the_one_message(refused: ServiceError, endpoint: str) -> None:
    assert refused.field == "endpoint"
    assert refused.message == (
        f"cannot reach an S3 server at http://{endpoint}: check the address, the port and HTTPS"
    )


def test_a_name_that_resolves_to_loopback_is_refused_before_connecting(server, names, settings):
    settings.RACECRAFT_OUTBOUND_ALLOW = []
    port = server.server_address[1]
    names["bucket.evil.example"] = ["127.0.0.1"]
    names["mixed.evil.example"] = ["93.184.216.34", "127.0.0.1"]  # public first, loopback next
    for endpoint in (f"bucket.evil.example:{port}", f"mixed.evil.example:{port}",
                     server.endpoint, f"[::ffff:127.0.0.1]:{port}"):  # fmt: skip
        assert_the_one_message(import_from(endpoint), endpoint)
    assert server.counts.requests == 0


def test_the_allow_list_does_not_extend_to_other_names(server, names, settings) -> None:
    settings.RACECRAFT_OUTBOUND_ALLOW = ["minio.lan"]
    names["evil.example"] = ["127.0.0.1"]
    endpoint = f"evil.example:{server.server_address[1]}"
    assert_the_one_message(import_from(endpoint), endpoint)
    assert server.counts.requests == 0


def test_a_redirect_to_loopback_is_not_followed(server, short_import, caplog) -> None:
    caplog.set_level(logging.DEBUG)
    server.mode = "redirect"
    assert_the_one_message(import_from(server.endpoint), server.endpoint)
    assert any(p.startswith(f"/{BUCKET}/{PREFIX}/model/") for p in server.counts.paths)
    assert server.internal.counts.requests == 0  # the metadata service was never asked
    assert "meta-data" not in caplog.text  # the Location is not logged either


def test_a_listing_that_never_ends_stops_at_the_request_bound(server, short_import) -> None:
    server.mode = "endless"
    assert_the_one_message(import_from(server.endpoint), server.endpoint)
    assert server.counts.requests == bucket_imports.BUCKET_MAX_REQUESTS


@pytest.mark.parametrize("mode", ["huge_listing", "huge_error", "huge_object"])
def test_a_300_mb_body_is_read_no_further_than_its_bound(server, short_import, mode) -> None:
    server.mode = mode
    baseline = _reset_peak_rss()
    assert_the_one_message(import_from(server.endpoint), server.endpoint)
    # The client reads at most the bound (a listing's 4 MB, an error's 64 kB, an object's
    # listed size or 64 kB) plus one chunk; the server could push only what sockets buffer.
    assert server.counts.bytes_sent < LISTING_BODY_BYTES + 32 * 2**20 < HUGE_BYTES
    assert _peak_rss() - baseline < 64 * 2**20


def test_a_body_bound_counts_bytes_read(server) -> None:
    server.mode = "huge_listing"
    policy = OutboundPolicy(allow=AllowList.parse(["127.0.0.1"]), deadline_s=30)
    with OutboundSession(Endpoint.parse(server.endpoint, secure=False), policy) as session:
        with pytest.raises(OutboundError, match="body over 100000 bytes"):
            session.request("GET", "/bucket?list-type=2", max_bytes=100_000)
        assert 100_000 < session.bytes_read <= 100_000 + 64 * 1024


def test_a_trickle_is_cut_off_at_the_deadline(server, short_import) -> None:
    server.mode = "trickle"
    started = time.monotonic()
    assert_the_one_message(import_from(server.endpoint), server.endpoint)
    # Cut by the deadline: before even the second byte, which comes 20 s after the first.
    assert time.monotonic() - started < 20
    assert server.counts.requests == 1 and server.counts.bytes_sent == 1


def test_html_is_not_an_s3_answer(server, short_import, caplog) -> None:
    caplog.set_level(logging.DEBUG)
    server.mode = "html"
    refused = import_from(server.endpoint)
    assert_the_one_message(refused, server.endpoint)
    assert "admin page" not in caplog.text and "html" not in refused.message


def test_every_failure_to_reach_reads_alike(server, short_import) -> None:
    """A closed port, an unknown host, a refused address and a server that answers HTML: the
    same sentence but for the address the user typed, so none tells what listens where."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        closed = f"127.0.0.1:{probe.getsockname()[1]}"
    server.mode = "html"
    endpoints = [closed, "no-such-host.invalid:9000", "169.254.169.254:80", server.endpoint]
    messages = {import_from(e).message.replace(e, "WHERE") for e in endpoints}
    assert len(messages) == 1


def _status_kb(field: str) -> int:
    with open("/proc/self/status") as status:
        lines = status.read().splitlines()
    for line in lines:
        if line.startswith(f"{field}:"):
            return int(line.split()[1]) * 1024
    raise AssertionError(f"no {field} in /proc/self/status")


def _reset_peak_rss() -> int:
    """Reset this process's peak resident memory (VmHWM) to now, and return it (bytes)."""
    with open("/proc/self/clear_refs", "w") as clear:
        clear.write("5")
    return _status_kb("VmHWM")


def _peak_rss() -> int:
    return _status_kb("VmHWM")
