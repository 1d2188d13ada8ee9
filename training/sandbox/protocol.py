"""Messages between the parent and a sandbox child over a pipe.

A frame is ``u32 length`` + ``u32 header length`` + a JSON header + raw array buffers. JSON and
plain-dtype numpy buffers only: the parent never unpickles anything the child sends (that would
hand the child code execution in the parent). Arrays appear in the JSON as
``{"__ndarray__": index, "dtype": "float32", "shape": [...]}``.
"""

from __future__ import annotations

import json
import os
import select
import struct
import time
from typing import Any

import numpy as np

_U32 = struct.Struct(">I")
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


def decode(body: bytes) -> Any:
    """The message of a frame body (without its length prefix); ProtocolError if malformed."""
    try:
        (hlen,) = _U32.unpack_from(body, 0)
        header = json.loads(body[4 : 4 + hlen])
        offset = 4 + hlen
        specs: list[dict[str, Any]] = []
        _collect_specs(header["m"], specs)
        sizes = [int(n) for n in header["b"]]
        arrays: list[np.ndarray] = []
        for size in sizes:
            arrays.append(np.frombuffer(body, dtype=np.uint8, count=size, offset=offset))
            offset += size
        if offset != len(body):
            raise ProtocolError("frame length mismatch")
        for spec in specs:
            i = int(spec["__ndarray__"])
            dtype = str(spec["dtype"])
            if dtype not in ALLOWED_DTYPES:
                raise ProtocolError(f"dtype {dtype!r} refused")
            shape = tuple(int(n) for n in spec["shape"])
            arrays[i] = arrays[i].view(dtype).reshape(shape).copy()
        return _decode_value(header["m"], arrays)
    except ProtocolError:
        raise
    except Exception as exc:  # noqa: BLE001 - anything malformed is a protocol error
        raise ProtocolError(f"malformed message: {type(exc).__name__}: {exc}") from None


def _collect_specs(value: Any, out: list[dict[str, Any]]) -> None:
    if isinstance(value, dict):
        if "__ndarray__" in value:
            out.append(value)
        else:
            for v in value.values():
                _collect_specs(v, out)
    elif isinstance(value, list):
        for v in value:
            _collect_specs(v, out)


def write_message(fd: int, message: Any) -> None:
    """Write one frame to ``fd`` (blocking)."""
    data = memoryview(encode(message))
    while data:
        n = os.write(fd, data)
        data = data[n:]


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
