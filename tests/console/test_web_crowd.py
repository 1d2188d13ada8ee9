"""The web server as ``manage.py up`` starts it (console/launcher.py ``web_spec``) is ready for
a race day's crowd: its listen queue holds 1024 connections (the kernel's
``net.core.somaxconn`` permitting), not Twisted's 50, and a websocket may take 30 s to be
accepted, not 5 (500 viewers arriving at once: ``bench/bench_race.py --viewers 500``)."""

from __future__ import annotations

import shutil
import socket
import subprocess
from pathlib import Path

import pytest

from console.launcher import (
    WEB_HANDSHAKE_TIMEOUT_S,
    WEB_LISTEN_BACKLOG,
    ConsoleOptions,
    Supervisor,
    daphne_server_args,
    web_spec,
)
from tests.support import free_port


def test_daphne_is_told_its_listen_queue_and_handshake_timeout() -> None:
    assert daphne_server_args("127.0.0.1", 8000) == [
        "-e", "tcp:port=8000:interface=127.0.0.1:backlog=1024",
        "--websocket_connect_timeout", "30",
    ]  # fmt: skip
    # IPv6 addresses as daphne's own -b writes them into Twisted's endpoint string.
    assert daphne_server_args("::", 80)[1] == r"tcp:port=80:interface=\:\::backlog=1024"
    assert daphne_server_args("[::1]", 80)[1] == r"tcp:port=80:interface=\:\:1:backlog=1024"
    assert (WEB_LISTEN_BACKLOG, WEB_HANDSHAKE_TIMEOUT_S) == (1024, 30)


def _listens(port: int) -> bool:
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("ss") is None, reason="needs iproute2's ss")
def test_the_web_server_listens_with_a_queue_for_a_crowd(child_env) -> None:
    port = free_port()
    somaxconn = int(Path("/proc/sys/net/core/somaxconn").read_text())
    with Supervisor(stop_timeout=10) as sup:
        sup.start(web_spec(ConsoleOptions(host="127.0.0.1", port=port), child_env))
        sup.wait_until(lambda: _listens(port), what="web server", timeout=120)
        out = subprocess.run(["ss", "-Hltn", f"sport = :{port}"], capture_output=True,
                             text=True, check=True).stdout.split()  # fmt: skip
    # A listening socket's Send-Q (the 4th column) is its backlog.
    assert int(out[2]) == min(WEB_LISTEN_BACKLOG, somaxconn), out
