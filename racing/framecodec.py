"""The live broadcast frame's binary format, written once: the race's worker encodes each frame
with :func:`encode_frame`; the web process, the bench and the tests read it with
:func:`decode_frame` (or :func:`decode_header`, which skips the picture).

A frame is one binary websocket message: a 4-byte big-endian length ``n``, ``n`` bytes of
UTF-8 JSON (an object: the header, e.g. ``{"timing": ..., "layout": ..., "t": <unix time>}``),
then the JPEG. The browser reads the same layout (``static/leaderboard/broadcast.js``).

Decoding is bounded: a header over :data:`MAX_HEADER_BYTES`, JSON nested deeper than
:data:`MAX_DEPTH`, a frame over :data:`MAX_FRAME_BYTES`, a header that is not a JSON object, or
a truncated message raise :class:`FrameError` (a ``ValueError``) with the reason.
"""

from __future__ import annotations

import json
import struct
from itertools import accumulate

MAX_HEADER_BYTES = 64 * 1024
MAX_FRAME_BYTES = 8 * 1024 * 1024
MAX_DEPTH = 12
_LENGTH = struct.Struct("!I")


class FrameError(ValueError):
    """A frame message that cannot be read (truncated, garbage, oversize)."""


def encode_frame(header: dict, jpeg: bytes) -> bytes:
    """One frame message: length, JSON header, JPEG. Raises :class:`FrameError` for a header or
    frame the decoder would refuse."""
    if not isinstance(header, dict):
        raise FrameError("a frame header is a JSON object")
    data = json.dumps(header, separators=(",", ":"), allow_nan=False).encode()
    if len(data) > MAX_HEADER_BYTES:
        raise FrameError(f"frame header of {len(data)} bytes is over {MAX_HEADER_BYTES}")
    if _depth(header) > MAX_DEPTH:
        raise FrameError(f"frame header nested deeper than {MAX_DEPTH}")
    payload = _LENGTH.pack(len(data)) + data + bytes(jpeg)
    if len(payload) > MAX_FRAME_BYTES:
        raise FrameError(f"frame of {len(payload)} bytes is over {MAX_FRAME_BYTES}")
    return payload


def decode_header(data: bytes | bytearray | memoryview) -> tuple[dict, int]:
    """The frame's header and where its JPEG starts."""
    view = memoryview(data)
    if len(view) > MAX_FRAME_BYTES:
        raise FrameError(f"frame of {len(view)} bytes is over {MAX_FRAME_BYTES}")
    if len(view) < _LENGTH.size:
        raise FrameError("frame truncated: no header length")
    (length,) = _LENGTH.unpack(view[: _LENGTH.size])
    if length > MAX_HEADER_BYTES:
        raise FrameError(f"frame header of {length} bytes is over {MAX_HEADER_BYTES}")
    end = _LENGTH.size + length
    if len(view) < end:
        raise FrameError("frame truncated inside its header")
    raw = bytes(view[_LENGTH.size : end])
    if _raw_depth(raw) > MAX_DEPTH:
        raise FrameError(f"frame header nested deeper than {MAX_DEPTH}")
    try:
        header = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise FrameError(f"frame header is not JSON: {exc}") from None
    if not isinstance(header, dict):
        raise FrameError("frame header is not a JSON object")
    return header, end


def decode_frame(data: bytes | bytearray | memoryview) -> tuple[dict, bytes]:
    """``(header, jpeg)`` of a frame message."""
    header, start = decode_header(data)
    return header, bytes(memoryview(data)[start:])


def frame_time(data: bytes) -> float | None:
    """The header's ``t`` (unix time the worker built the frame), or ``None`` when the frame
    cannot be read or has none."""
    try:
        t = decode_header(data)[0].get("t")
    except FrameError:
        return None
    return float(t) if isinstance(t, (int, float)) and not isinstance(t, bool) else None


def _depth(value, level: int = 1) -> int:
    if level > MAX_DEPTH:
        return level
    if isinstance(value, dict):
        return max((_depth(v, level + 1) for v in value.values()), default=level)
    if isinstance(value, (list, tuple)):
        return max((_depth(v, level + 1) for v in value), default=level)
    return level - 1


_NOT_BRACKETS = bytes(b for b in range(256) if b not in b"[]{}")
_PARENS = bytes.maketrans(b"[{]}", b"(())")
_STEP = {0x28: 1, 0x29: -1}


def _raw_depth(raw: bytes) -> int:
    """How deep brackets nest in the JSON text, strings skipped: checked before parsing, so a
    deeply nested header never reaches the parser's recursion.

    Every reader of every frame runs this (the bench's 500 viewers 7,500 times a second), so
    the usual header takes a fast path: without an escaped quote or backslash in it, the text
    outside strings is every other piece between quotes (an unterminated string's rest is
    dropped, as the byte walk drops it), and only its brackets count, a few dozen, taken in
    C (about 3 us a header here instead of 45 for the byte walk). A header with ``\\"``
    or ``\\\\`` in it takes the byte walk (:func:`_walk_depth`); both agree on any text."""
    if b'\\"' in raw or b"\\\\" in raw:
        return _walk_depth(raw)
    brackets = b"".join(raw.split(b'"')[::2]).translate(_PARENS, _NOT_BRACKETS)
    depth, rest = 0, brackets
    while rest:  # balanced: each pass takes the innermost pairs away, one level
        inner = rest.replace(b"()", b"")
        if len(inner) == len(rest):  # unbalanced: walk them
            return max(accumulate((_STEP[b] for b in brackets), initial=0))
        depth, rest = depth + 1, inner
    return depth


def _walk_depth(raw: bytes) -> int:
    """:func:`_raw_depth` byte by byte, any escapes."""
    depth = deepest = 0
    in_string = escaped = False
    for byte in raw:
        if in_string:
            if escaped:
                escaped = False
            elif byte == 0x5C:  # backslash
                escaped = True
            elif byte == 0x22:
                in_string = False
        elif byte == 0x22:
            in_string = True
        elif byte in (0x7B, 0x5B):
            depth += 1
            deepest = max(deepest, depth)
        elif byte in (0x7D, 0x5D):
            depth -= 1
    return deepest
