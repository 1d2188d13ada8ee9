"""The one way out: HTTP requests to an address a user supplies (a bucket to import from
today, a webhook or a URL import tomorrow) go through :class:`OutboundSession`, never through
urllib, requests or an SDK's own client.

A user who names the address must not make the server reach what only the server can reach
(its loopback, the LAN, a cloud's metadata service at ``169.254.169.254``), nor hold it busy or
fill its memory. So a session:

- resolves the host once and refuses it when any of its addresses is loopback, private,
  link-local, shared (``100.64.0.0/10``), multicast, reserved or unspecified, IPv4 or IPv6 (an
  IPv4 address mapped or embedded in IPv6 is judged as that IPv4 address), unless the
  operator's allow-list (:attr:`OutboundPolicy.allow`: host names, addresses, networks; for a
  MinIO on the LAN) names it; then it connects to an address it checked, never looking the
  name up again (a second answer could point elsewhere);
- follows no redirect (a 3xx is a failure);
- bounds every body it reads by bytes (the caller's bound, else
  :attr:`OutboundPolicy.max_body_bytes`), refusing a larger ``Content-Length`` before reading;
- bounds the whole session by a deadline, checked before every read from the socket (so a
  server trickling a byte at a time is cut off at the deadline, headers included), and by a
  number of requests.

Every failure is one :class:`OutboundError` whose ``detail`` is ours (for logs: which rule,
never a byte the server sent); callers show the user one sentence for all of them, so an
answer cannot tell which internal ports listen. Each request is logged at INFO with the host,
the outcome and the size, never a body. Django-free: the caller passes the policy.
"""

from __future__ import annotations

import http.client
import io
import ipaddress
import logging
import re
import socket
import ssl
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

from training.outbound_allow import Network, parse_allow_entries

log = logging.getLogger(__name__)

Address = ipaddress.IPv4Address | ipaddress.IPv6Address

_HOST_RE = re.compile(r"^(?=.{1,253}$)[a-z0-9_]([a-z0-9_-]{0,62})(\.[a-z0-9_]([a-z0-9_-]{0,62}))*$")
_SHARED = ipaddress.ip_network("100.64.0.0/10")  # carrier-grade NAT (RFC 6598)
_NAT64 = ipaddress.ip_network("64:ff9b::/96")  # an IPv4 address in its last 32 bits
_CHUNK = 64 * 1024  # bytes asked of the socket per read


class OutboundError(Exception):
    """A request to a user's address failed or was refused. ``detail`` says which rule, in our
    words only (``"address not allowed"``, ``"redirect"``, ``"deadline"``...), for logs; show
    the user one sentence for every OutboundError."""

    def __init__(self, detail: str) -> None:
        super().__init__(detail)
        self.detail = detail


@dataclass(frozen=True)
class AllowList:
    """Destinations the operator allows although their addresses are not public: host names
    (as the user writes them, any case, no trailing dot) and networks."""

    hosts: frozenset[str] = frozenset()
    networks: tuple[Network, ...] = ()

    @classmethod
    def parse(cls, entries: Iterable[str]) -> AllowList:
        """From ``"minio.lan"``, ``"10.0.0.5"``, ``"192.168.1.0/24"``, ``"::1"``... Raises
        ValueError naming an entry that is neither a host name nor an address or network
        (:func:`training.outbound_allow.parse_allow_entries`, which settings check with)."""
        hosts, networks = parse_allow_entries(entries)
        return cls(hosts, networks)

    def allows(self, host: str, address: Address) -> bool:
        if host.lower().rstrip(".") in self.hosts:
            return True
        return any(address in net or _embedded_v4(address) in net for net in self.networks)


@dataclass(frozen=True)
class OutboundPolicy:
    """The bounds of one session (seconds, bytes, requests) and the operator's allow-list."""

    allow: AllowList = field(default_factory=AllowList)
    connect_timeout_s: float = 10.0
    read_timeout_s: float = 30.0
    """The longest wait for one read from the socket (the deadline may cut it shorter)."""
    deadline_s: float = 120.0
    """The whole session: every connection, request and read."""
    max_requests: int = 100
    max_body_bytes: int = 1 << 20
    """A body's bound when the caller names none."""


def _embedded_v4(address: Address) -> Address:
    """The IPv4 address an IPv6 one carries (mapped ``::ffff:a.b.c.d``, 6to4 ``2002::/16``,
    NAT64 ``64:ff9b::/96``), else the address itself."""
    if isinstance(address, ipaddress.IPv6Address):
        if address.ipv4_mapped is not None:
            return address.ipv4_mapped
        if address.sixtofour is not None:
            return address.sixtofour
        if address in _NAT64:
            return ipaddress.IPv4Address(int(address) & 0xFFFFFFFF)
    return address


def address_is_public(address: Address | str) -> bool:
    """Whether ``address`` is a public unicast address: not loopback, private, link-local,
    shared (100.64.0.0/10), multicast, reserved, unspecified nor documentation; an IPv6
    address carrying an IPv4 one is judged by that one too."""
    if isinstance(address, str):
        address = ipaddress.ip_address(address.split("%", 1)[0])
    embedded = _embedded_v4(address)
    mapped = isinstance(address, ipaddress.IPv6Address) and address.ipv4_mapped is not None
    # A mapped address is the IPv4 one (::ffff:0:0/96 itself counts as private); 6to4 and
    # NAT64 addresses must be public both as themselves and as the IPv4 address they carry.
    for candidate in {embedded} if mapped else {address, embedded}:
        if (
            not candidate.is_global
            or candidate.is_private
            or candidate.is_loopback
            or candidate.is_link_local
            or candidate.is_multicast
            or candidate.is_reserved
            or candidate.is_unspecified
            or candidate in _SHARED
            or getattr(candidate, "is_site_local", False)
        ):
            return False
    return True


@dataclass(frozen=True)
class Endpoint:
    """Where a session talks: ``host`` (a name or an address, IPv6 without brackets), ``port``
    and whether over TLS."""

    host: str
    port: int
    secure: bool

    @classmethod
    def parse(cls, text: str, *, secure: bool) -> Endpoint:
        """From ``host``, ``host:port``, ``[v6]:port``, with an optional ``http://`` or
        ``https://`` (which then decides ``secure``) and trailing ``/``. Raises ValueError."""
        text = text.strip()
        for scheme, is_secure in (("http://", False), ("https://", True)):
            if text.lower().startswith(scheme):
                text, secure = text[len(scheme) :], is_secure
        text = text.rstrip("/")
        if not text or "/" in text or "@" in text or any(c.isspace() for c in text):
            raise ValueError("not host:port")
        port = 443 if secure else 80
        if text.startswith("["):
            host, bracket, rest = text[1:].partition("]")
            if not bracket or (rest and not rest.startswith(":")):
                raise ValueError("not host:port")
            port_text = rest[1:] if rest else ""
        elif text.count(":") == 1:
            host, port_text = text.split(":")
        else:
            host, port_text = text, ""
        if port_text:
            if not port_text.isdigit() or not 0 < int(port_text) < 65536:
                raise ValueError("not a port")
            port = int(port_text)
        host = host.lower()
        try:
            ipaddress.ip_address(host)
        except ValueError:
            if not _HOST_RE.match(host.rstrip(".")):
                raise ValueError("not a host name") from None
        return cls(host, port, secure)

    @property
    def netloc(self) -> str:
        """``host[:port]`` as the Host header carries it (the port only when not the default)."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        default = 443 if self.secure else 80
        return host if self.port == default else f"{host}:{self.port}"

    def __str__(self) -> str:
        return f"{'https' if self.secure else 'http'}://{self.netloc}"


@dataclass(frozen=True)
class OutboundResponse:
    status: int
    headers: Mapping[str, str]
    body: bytes


class _Budget:
    """The session's clock and request count."""

    def __init__(self, policy: OutboundPolicy) -> None:
        self.policy = policy
        self.ends = time.monotonic() + policy.deadline_s
        self.requests = 0

    def wait_s(self, longest: float) -> float:
        """How long the next socket operation may wait; OutboundError once the deadline is
        past."""
        left = self.ends - time.monotonic()
        if left <= 0:
            raise OutboundError("deadline")
        return min(longest, left)


class _DeadlineReader(io.RawIOBase):
    """The socket's bytes, each read waiting at most until the session's deadline."""

    def __init__(self, owner: _DeadlineSocket) -> None:
        self._owner = owner

    def readable(self) -> bool:
        return True

    def readinto(self, buffer) -> int:  # type: ignore[override]
        sock, budget = self._owner.sock, self._owner.budget
        sock.settimeout(budget.wait_s(budget.policy.read_timeout_s))
        try:
            return sock.recv_into(buffer)
        except TimeoutError:
            raise OutboundError(
                "deadline" if time.monotonic() >= budget.ends else "read timeout"
            ) from None

    def close(self) -> None:
        if not self.closed:
            super().close()
            self._owner.release()


class _DeadlineSocket:
    """What http.client needs of a socket (sendall, makefile, close), under the deadline. As a
    real socket's, ``close`` waits for the files it made: http.client closes the connection
    while its response still reads the body."""

    def __init__(self, sock: socket.socket, budget: _Budget) -> None:
        self.sock, self.budget = sock, budget
        self._users = 1  # this object, and one per file made
        self._closed = False

    def sendall(self, data: bytes) -> None:
        self.sock.settimeout(self.budget.wait_s(self.budget.policy.read_timeout_s))
        self.sock.sendall(data)

    def makefile(self, mode: str = "rb", *args: object, **kwargs: object) -> io.BufferedReader:
        self._users += 1
        return io.BufferedReader(_DeadlineReader(self), _CHUNK)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self.release()

    def release(self) -> None:
        self._users -= 1
        if self._users == 0:
            self.sock.close()


class _GuardedConnection(http.client.HTTPConnection):
    """http.client's connection, connecting to one of the checked addresses (TLS verified
    against the host name, sent as SNI)."""

    def __init__(self, session: OutboundSession) -> None:
        super().__init__(session.endpoint.host, session.endpoint.port)
        self._session = session

    def connect(self) -> None:
        session, budget = self._session, self._session._budget
        endpoint = session.endpoint
        last: OSError | None = None
        for address in session.addresses():
            try:
                raw = socket.create_connection(
                    (str(address), endpoint.port),
                    timeout=budget.wait_s(budget.policy.connect_timeout_s),
                )
            except OSError as exc:
                last = exc
                continue
            try:
                if endpoint.secure:
                    raw = session.ssl_context.wrap_socket(raw, server_hostname=endpoint.host)
            except (OSError, ssl.SSLError):
                raw.close()
                raise OutboundError("TLS handshake failed") from None
            self.sock = _DeadlineSocket(raw, budget)  # type: ignore[assignment]
            return
        detail = "connection timed out" if isinstance(last, TimeoutError) else "cannot connect"
        raise OutboundError(detail)


class OutboundSession:
    """Requests to one endpoint a user named, under one :class:`OutboundPolicy`: its deadline
    starts when the session is made. Use as a context manager (or call :meth:`close`)."""

    def __init__(
        self,
        endpoint: Endpoint,
        policy: OutboundPolicy,
        *,
        ssl_context: ssl.SSLContext | None = None,
    ) -> None:
        self.endpoint = endpoint
        self.policy = policy
        self.ssl_context = ssl_context or ssl.create_default_context()
        self._budget = _Budget(policy)
        self._addresses: list[Address] | None = None
        self._conn: _GuardedConnection | None = None
        self.bytes_read = 0
        """Body bytes read in all, for tests and logs."""

    def __enter__(self) -> OutboundSession:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self._conn is not None:
            self._conn.close()
            self._conn = None

    @property
    def requests(self) -> int:
        return self._budget.requests

    def addresses(self) -> list[Address]:
        """The endpoint's addresses, looked up once per session and all checked: one that is
        not public and not allowed refuses the host (a name that answers a public address
        and a loopback one is not trusted with either)."""
        if self._addresses is None:
            host, port = self.endpoint.host, self.endpoint.port
            try:
                infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
            except (OSError, UnicodeError):
                raise OutboundError("unknown host") from None
            found = list(dict.fromkeys(
                ipaddress.ip_address(str(info[4][0]).split("%", 1)[0]) for info in infos
            ))  # fmt: skip
            allow = self.policy.allow
            if not found or any(
                not address_is_public(a) and not allow.allows(host, a) for a in found
            ):
                raise OutboundError("address not allowed")
            self._addresses = found
        return self._addresses

    def request(
        self,
        method: str,
        target: str,
        headers: Mapping[str, str] | None = None,
        *,
        max_bytes: int | None = None,
    ) -> OutboundResponse:
        """Send ``method target`` (``target``: the path and query, already encoded) and read
        the whole answer, its body at most ``max_bytes``. A 3xx, a larger body, the deadline,
        the request count or any connection failure raises :class:`OutboundError`."""
        try:
            return self._request(method, target, headers, max_bytes)
        except OutboundError as exc:
            self.close()
            log.info("outbound %s %s refused: %s", method, self.endpoint, exc.detail)
            raise

    def _request(
        self, method: str, target: str, headers: Mapping[str, str] | None, max_bytes: int | None
    ) -> OutboundResponse:
        budget = self._budget
        if budget.requests >= self.policy.max_requests:
            raise OutboundError("too many requests")
        budget.requests += 1
        bound = self.policy.max_body_bytes if max_bytes is None else max_bytes
        self.addresses()
        # A connection per request: no stale kept-alive connection to retry on.
        self.close()
        self._conn = _GuardedConnection(self)
        sent = {"Host": self.endpoint.netloc, "Connection": "close", **(headers or {})}
        response: http.client.HTTPResponse | None = None
        try:
            self._conn.request(method, target, headers=sent)
            response = self._conn.getresponse()
            if 300 <= response.status < 400:
                raise OutboundError(f"redirect ({response.status})")
            length = response.getheader("Content-Length")
            if length is not None and (not length.isdigit() or int(length) > bound):
                raise OutboundError(f"body over {bound} bytes ({response.status})")
            body = self._read_body(response, bound)
        except (http.client.HTTPException, OSError, ValueError) as exc:
            raise OutboundError(_connection_failure(exc)) from None
        finally:
            if response is not None:
                response.close()
            self.close()
        log.info("outbound %s %s: %d, %d bytes", method, self.endpoint, response.status, len(body))
        headers_read = {name.lower(): value for name, value in response.getheaders()}
        return OutboundResponse(response.status, headers_read, body)

    def _read_body(self, response: http.client.HTTPResponse, bound: int) -> bytes:
        body = bytearray()
        while True:
            chunk = response.read1(_CHUNK)
            if not chunk:
                return bytes(body)
            body += chunk
            self.bytes_read += len(chunk)
            if len(body) > bound:
                raise OutboundError(f"body over {bound} bytes ({response.status})")


def _connection_failure(exc: BaseException) -> str:
    if isinstance(exc, TimeoutError):
        return "read timeout"
    if isinstance(exc, http.client.HTTPException):
        return "not an HTTP answer"
    return "connection failed"
