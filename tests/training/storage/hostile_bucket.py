"""A hostile "S3 server" on loopback, for the guarded outbound client's tests: a real HTTP
server (``http.server.ThreadingHTTPServer`` in a thread) that answers as a racer's bucket
server would to hurt the console: redirects to an internal service, a listing that never ends,
300 MB bodies streamed lazily, a byte every 20 s, HTML. It counts the requests it got and the
bytes it managed to send, so a test asserts what the client did, not how long it took."""

from __future__ import annotations

import http.server
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from urllib.parse import parse_qs, urlsplit

BUCKET, PREFIX = "bucket", "rl-deepracer-sagemaker"
HUGE_BYTES = 300 * 1024 * 1024
"""What a huge body would be, were it read to its end (bytes)."""
_CHUNK = b"x" * (64 * 1024)
_LOCATION = (
    b'<?xml version="1.0" encoding="UTF-8"?>\n<LocationConstraint '
    b'xmlns="http://s3.amazonaws.com/doc/2006-03-01/">us-east-1</LocationConstraint>'
)


@dataclass
class Counts:
    """What the server saw and sent; the lock guards them (each request has its thread)."""

    requests: int = 0
    bytes_sent: int = 0
    paths: list[str] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def add(self, *, request: str = "", sent: int = 0) -> None:
        with self.lock:
            if request:
                self.requests += 1
                self.paths.append(request)
            self.bytes_sent += sent


def _listing(prefix: str, keys: dict[str, int], token: str = "") -> bytes:
    contents = "".join(
        f"<Contents><Key>{k}</Key><Size>{n}</Size></Contents>" for k, n in keys.items()
    )
    more = f"<IsTruncated>true</IsTruncated><NextContinuationToken>{token}</NextContinuationToken>"
    truncated = more if token else "<IsTruncated>false</IsTruncated>"
    return (f'<?xml version="1.0" encoding="UTF-8"?><ListBucketResult xmlns="http://s3.amazonaws.'
            f'com/doc/2006-03-01/"><Name>{BUCKET}</Name><Prefix>{prefix}</Prefix>{contents}'
            f"{truncated}</ListBucketResult>").encode()  # fmt: skip


class _Handler(http.server.BaseHTTPRequestHandler):
    server: HostileServer

    def log_message(self, *args: object) -> None:  # quiet
        pass

    def do_GET(self) -> None:
        server = self.server
        server.counts.add(request=self.path)
        url = urlsplit(self.path)
        query = parse_qs(url.query, keep_blank_values=True)
        mode = server.mode
        if mode == "trickle":
            return self._trickle()
        if mode == "html":
            return self._send(200, b"<html><body>an internal admin page</body></html>", "text/html")
        if mode == "huge_error":
            return self._stream(500)
        if "location" in query:
            return self._send(200, _LOCATION)
        if "list-type" in query:
            prefix = query.get("prefix", [""])[0]
            if mode == "endless":
                token = f"t{server.counts.requests}"  # a new token each time, never the end
                return self._send(200, _listing(prefix, {}, token))
            if mode == "huge_listing":
                return self._stream(200)
            keys = {f"{PREFIX}/model/model_metadata.json": 100, f"{PREFIX}/model/model_3.pb": 100,
                    f"{PREFIX}/reward_function.py": 64}  # fmt: skip
            here = {k: n for k, n in keys.items() if k.rpartition("/")[0] + "/" == prefix}
            return self._send(200, _listing(prefix, here))
        if mode == "redirect":  # the object: "it moved" to the cloud's metadata service
            self.send_response(302)
            self.send_header("Location", f"{server.internal_url}/latest/meta-data/iam/")
            self.send_header("Content-Length", "0")
            self.end_headers()
            return None
        if mode == "huge_object":
            return self._stream(200)
        return self._send(200, b"{}")

    def _send(self, status: int, body: bytes, kind: str = "application/xml") -> None:
        self.send_response(status)
        self.send_header("Content-Type", kind)
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)
        self.server.counts.add(sent=len(body))

    def _stream(self, status: int) -> None:
        """HUGE_BYTES, a chunk at a time as the client reads (no length: read to the close)."""
        self.send_response(status)
        self.send_header("Content-Type", "application/xml")
        self.end_headers()
        self.close_connection = True
        try:
            for _ in range(HUGE_BYTES // len(_CHUNK)):
                self.wfile.write(_CHUNK)
                self.server.counts.add(sent=len(_CHUNK))
        except OSError:  # the client hung up
            return

    def _trickle(self) -> None:
        """The status line a byte every 20 s: each read gets a byte before its timeout."""
        try:
            for byte in b"HTTP/1.1 200 OK\r\nContent-Length: 0\r\n\r\n":
                self.wfile.write(bytes([byte]))
                self.wfile.flush()
                self.server.counts.add(sent=1)
                if self.server.stop.wait(20):
                    return
        except OSError:
            return


class HostileServer(http.server.ThreadingHTTPServer):
    daemon_threads = True

    def __init__(self, internal_url: str = "") -> None:
        super().__init__(("127.0.0.1", 0), _Handler)
        self.mode = "ok"
        self.counts = Counts()
        self.stop = threading.Event()
        self.internal_url = internal_url

    @property
    def endpoint(self) -> str:
        return f"127.0.0.1:{self.server_address[1]}"


@contextmanager
def hostile_server(internal_url: str = "") -> Iterator[HostileServer]:
    server = HostileServer(internal_url)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield server
    finally:
        server.stop.set()
        server.shutdown()
        server.server_close()
        thread.join(timeout=30)
