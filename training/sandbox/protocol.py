"""Messages between the parent and a sandbox child over a pipe.

A frame is ``u32 length`` + ``u32 header length`` + a JSON header + raw array buffers. JSON and
plain-dtype numpy buffers only: the parent never unpickles anything the child sends (that would
hand the child code execution in the parent). Arrays appear in the JSON as
``{"__ndarray__": index, "dtype": "float32", "shape": [...]}``.

Nothing a child sends is trusted, so :func:`decode` bounds a frame before it builds anything:
the JSON header's size (:data:`MAX_HEADER_BYTES`), how many containers and items it may declare
(counted on the raw bytes, so a header of nested empty lists is refused before one list exists;
a JSON value costs far more memory than its bytes), the nesting depth, the arrays' count and
shapes against the bytes that came with them, and one array per buffer (a buffer named twice is
refused: decoding copies each byte that came at most once).
"""

from __future__ import annotations

import json
import math
import os
import select
import struct
import time
from typing import Any

import numpy as np

_U32 = struct.Struct(">I")
#: The JSON part of one frame; arrays travel beside it as raw bytes.
MAX_HEADER_BYTES = 4 << 20
#: Lists and objects one header may hold (``[`` and ``{`` bytes, strings included).
MAX_CONTAINERS = 50_000
#: Items one header may hold (``,`` and ``:`` bytes, strings included).
MAX_ITEMS = 500_000
#: Nesting of lists and objects.
MAX_DEPTH = 32
#: Arrays in one frame.
MAX_ARRAYS = 256
ALLOWED_DTYPES = frozenset(
    {
        "bool",
        "int8",
        "int16",
        "int32",
        "int64",
        "uint8",
        "uint16",
        "uint32",
        "uint64",
        "float16",
        "float32",
        "float64",
    }
)


class ProtocolError(Exception):
    """A frame that is too large, truncated or not valid."""


def _encode_value(value: Any, buffers: list[bytes]) -> Any:
    if isinstance(value, np.ndarray):
        arr = np.ascontiguousarray(value)
        if arr.dtype.name not in ALLOWED_DTYPES:
            raise TypeError(f"arrays of dtype {arr.dtype} cannot be sent")
        buffers.append(arr.tobytes())
        return {"__ndarray__": len(buffers) - 1, "dtype": arr.dtype.name, "shape": arr.shape}
    if isinstance(value, dict):
        return {str(k): _encode_value(v, buffers) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_encode_value(v, buffers) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def encode(message: Any) -> bytes:
    """One frame for ``message`` (JSON-able values and numpy arrays)."""
    buffers: list[bytes] = []
    header = json.dumps(
        {"m": _encode_value(message, buffers), "b": [len(b) for b in buffers]},
        allow_nan=True,
        separators=(",", ":"),
    ).encode()
    body = _U32.pack(len(header)) + header + b"".join(buffers)
    return _U32.pack(len(body)) + body


def _decode_value(value: Any, arrays: list[np.ndarray]) -> Any:
    if isinstance(value, dict):
        if "__ndarray__" in value:
            return arrays[int(value["__ndarray__"])]
        return {k: _decode_value(v, arrays) for k, v in value.items()}
    if isinstance(value, list):
        return [_decode_value(v, arrays) for v in value]
    return value


def check_header(raw: bytes) -> None:
    """Refuse a JSON header too large or declaring too many values, before it is parsed.

    The counts are taken on the bytes (``bytes.count`` in C), so a bracket inside a string
    counts too: the bounds are generous and can only over-count."""
    if len(raw) > MAX_HEADER_BYTES:
        raise ProtocolError(
            f"a header of {len(raw):,} bytes is over the {MAX_HEADER_BYTES:,} limit"
        )
    containers = raw.count(b"[") + raw.count(b"{")
    if containers > MAX_CONTAINERS:
        raise ProtocolError(f"{containers:,} lists or objects; at most {MAX_CONTAINERS:,}")
    items = raw.count(b",") + raw.count(b":")
    if items > MAX_ITEMS:
        raise ProtocolError(f"{items:,} values; at most {MAX_ITEMS:,}")


def decode(body: bytes) -> Any:
    """The message of a frame body (without its length prefix); ProtocolError if malformed."""
    try:
        (hlen,) = _U32.unpack_from(body, 0)
        if hlen > len(body) - 4:
            raise ProtocolError("frame length mismatch")
        raw = body[4 : 4 + hlen]
        check_header(raw)
        header = json.loads(raw)
        if not isinstance(header, dict) or not isinstance(header.get("b"), list):
            raise ProtocolError("not a frame header")
        offset = 4 + hlen
        specs: list[dict[str, Any]] = []
        _collect_specs(header.get("m"), specs)
        if len(header["b"]) > MAX_ARRAYS or len(specs) > MAX_ARRAYS:
            raise ProtocolError(f"more than {MAX_ARRAYS} arrays")
        sizes = [int(n) for n in header["b"]]
        if any(n < 0 for n in sizes) or offset + sum(sizes) != len(body):
            raise ProtocolError("frame length mismatch")
        arrays: list[np.ndarray] = []
        for size in sizes:
            arrays.append(np.frombuffer(body, dtype=np.uint8, count=size, offset=offset))
            offset += size
        if offset != len(body):
            raise ProtocolError("frame length mismatch")
        views: dict[int, tuple[str, tuple[int, ...]]] = {}
        for spec in specs:
            i = int(spec["__ndarray__"])
            # Each array has a buffer of its own (encode): a buffer named twice would be
            # copied once per name, 256 copies of a 32 MB buffer from one frame (issue 52).
            if i in views or not 0 <= i < len(arrays):
                raise ProtocolError(f"array buffer {i} named twice or missing")
            dtype = str(spec["dtype"])
            if dtype not in ALLOWED_DTYPES:
                raise ProtocolError(f"dtype {dtype!r} refused")
            shape = tuple(int(n) for n in spec["shape"])
            if len(shape) > MAX_DEPTH or any(n < 0 for n in shape):
                raise ProtocolError("bad array shape")
            if math.prod(shape) * np.dtype(dtype).itemsize != sizes[i]:
                raise ProtocolError("an array's shape does not match its bytes")
            views[i] = (dtype, shape)
        # Checked in full before the first copy: a refused frame costs no copy at all.
        for i, (dtype, shape) in views.items():
            arrays[i] = arrays[i].view(dtype).reshape(shape).copy()
        return _decode_value(header["m"], arrays)
    except ProtocolError:
        raise
    except Exception as exc:  # noqa: BLE001 - anything malformed is a protocol error
        raise ProtocolError(f"malformed message: {type(exc).__name__}: {exc}") from None


def _collect_specs(value: Any, out: list[dict[str, Any]]) -> None:
    """The array placeholders in ``value``, walked without recursion; refuses a nesting
    deeper than :data:`MAX_DEPTH`."""
    stack: list[tuple[Any, int]] = [(value, 0)]
    while stack:
        item, depth = stack.pop()
        if isinstance(item, dict | list):
            if depth >= MAX_DEPTH:
                raise ProtocolError(f"nested more than {MAX_DEPTH} deep")
            if isinstance(item, dict) and "__ndarray__" in item:
                out.append(item)
                continue
            children = item.values() if isinstance(item, dict) else item
            stack.extend((child, depth + 1) for child in children)


def write_message(fd: int, message: Any) -> None:
    """Write one frame to ``fd`` (blocking)."""
    data = memoryview(encode(message))
    while data:
        n = os.write(fd, data)
        data = data[n:]


def write_with_deadline(fd: int, data: bytes, deadline: float | None) -> None:
    """Write all of ``data`` to a non-blocking ``fd`` by ``deadline`` (monotonic seconds, None
    for no deadline). Raises TimeoutError when the reader stops taking data (a full pipe it
    never drains, or one it shrank), BrokenPipeError when it is gone."""
    view = memoryview(data)
    poller = select.poll()
    poller.register(fd, select.POLLOUT | select.POLLERR | select.POLLHUP)
    while view:
        try:
            n = os.write(fd, view)
        except BlockingIOError:
            n = 0
        view = view[n:]
        if not view:
            return
        wait = None if deadline is None else deadline - time.monotonic()
        if wait is not None and wait <= 0:
            raise TimeoutError
        events = poller.poll(None if wait is None else int(wait * 1000) + 1)
        if any(ev & (select.POLLERR | select.POLLHUP) for _, ev in events):
            raise BrokenPipeError("the reader closed the pipe")


class FrameReader:
    """Reads frames from a non-blocking fd with deadlines; refuses frames over ``max_bytes``."""

    def __init__(self, fd: int, max_bytes: int) -> None:
        self.fd = fd
        self.max_bytes = max_bytes
        self.buf = bytearray()
        os.set_blocking(fd, False)

    def _frame(self) -> bytes | None:
        if len(self.buf) < 4:
            return None
        (n,) = _U32.unpack_from(self.buf, 0)
        if n > self.max_bytes:
            raise ProtocolError(f"message of {n} bytes is over the {self.max_bytes} limit")
        if len(self.buf) < 4 + n:
            return None
        body = bytes(self.buf[4 : 4 + n])
        del self.buf[: 4 + n]
        return body

    def ready(self) -> bool:
        """Whether :meth:`read` would return (or raise) at once: a whole frame, one over the
        limit, or the pipe's end is there. Reads what the pipe holds, never waits."""
        while True:
            if len(self.buf) >= 4:
                (n,) = _U32.unpack_from(self.buf, 0)
                if n > self.max_bytes or len(self.buf) >= 4 + n:
                    return True
            try:
                chunk = os.read(self.fd, 1 << 20)
            except BlockingIOError:
                return False
            if not chunk:
                return True  # the end: read() raises EOFError
            self.buf += chunk

    def read(self, timeout: float | None) -> Any:
        """Next message. Raises TimeoutError at the deadline, EOFError when the pipe closed."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            body = self._frame()
            if body is not None:
                return decode(body)
            wait = None if deadline is None else max(0.0, deadline - time.monotonic())
            poller = select.poll()
            poller.register(self.fd, select.POLLIN | select.POLLHUP | select.POLLERR)
            if not poller.poll(None if wait is None else int(wait * 1000) + 1):
                if deadline is not None and time.monotonic() >= deadline:
                    raise TimeoutError
                continue
            try:
                chunk = os.read(self.fd, 1 << 20)
            except BlockingIOError:
                continue
            if not chunk:
                raise EOFError
            self.buf += chunk


def read_message_blocking(fd: int) -> Any:
    """Child side: read one frame from a blocking fd (EOFError when the parent is gone)."""

    def exactly(n: int) -> bytes:
        out = bytearray()
        while len(out) < n:
            chunk = os.read(fd, n - len(out))
            if not chunk:
                raise EOFError
            out += chunk
        return bytes(out)

    (n,) = _U32.unpack(exactly(4))
    return decode(exactly(n))
