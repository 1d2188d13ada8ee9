"""The operator's outbound allow-list (``RACECRAFT_OUTBOUND_ALLOW``), parsed in one place.

Pure and light (the standard library only): Django settings check the variable with it when
they load, and :class:`training.storage.outbound.AllowList` is built from it, so a value the
settings accept is exactly a value the guarded client understands, with one error message.
Settings may import this module; they may not import :mod:`training.storage` (import-linter).
"""

from __future__ import annotations

import ipaddress
import re
from collections.abc import Iterable

Network = ipaddress.IPv4Network | ipaddress.IPv6Network

_NAME_RE = re.compile(r"^[a-z0-9_][a-z0-9_.-]{0,252}$")


def parse_allow_entries(entries: Iterable[str]) -> tuple[frozenset[str], tuple[Network, ...]]:
    """The host names and networks of ``entries`` such as ``"minio.lan"``, ``"10.0.0.5"``,
    ``"192.168.1.0/24"``, ``"[::1]"``: names lower-cased without a trailing dot, an address
    as its one-address network, blank entries skipped. Raises ValueError naming the first
    entry that is neither a host name nor an IP address or network."""
    hosts: set[str] = set()
    networks: list[Network] = []
    for raw in entries:
        entry = raw.strip().lower().rstrip(".")
        if not entry:
            continue
        try:
            networks.append(ipaddress.ip_network(entry.strip("[]"), strict=False))
            continue
        except ValueError:
            pass
        if not _NAME_RE.match(entry):
            raise ValueError(f"{raw!r} is not a host name, an IP address or a network")
        hosts.add(entry)
    return frozenset(hosts), tuple(networks)
