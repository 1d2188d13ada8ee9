"""The live frame's one binary format (racing/framecodec.py): round trip and bad frames."""

from __future__ import annotations

import struct

import pytest

from racing.framecodec import (
    MAX_DEPTH,
    MAX_FRAME_BYTES,
    MAX_HEADER_BYTES,
    FrameError,
    decode_frame,
    decode_header,
    encode_frame,
    frame_time,
)

JPEG = b"\xff\xd8" + bytes(range(256)) * 40 + b"\xff\xd9"


def test_a_frame_round_trips() -> None:
    header = {"timing": {"clock_s": 12.47, "cars": [{"name": "Ada ✓", "gap_s": None}]},
              "t": 1_700_000_000.25}  # fmt: skip
    data = encode_frame(header, JPEG)
    assert data[:4] == struct.pack("!I", len(data) - 4 - len(JPEG))
    assert decode_frame(data) == (header, JPEG)
    assert decode_frame(memoryview(data)) == (header, JPEG)
    assert decode_header(data)[1] == len(data) - len(JPEG)
    assert frame_time(data) == 1_700_000_000.25
    assert decode_frame(encode_frame({}, b"")) == ({}, b"")


@pytest.mark.parametrize(
    ("data", "message"),
    [
        (b"", "no header length"),
        (b"\x00\x00", "no header length"),
        (b"\x00\x00\x00\x09not", "truncated inside its header"),
        (b"\x00\x00\x00\x09not json!", "not JSON"),
        (b"\x00\x00\x00\x02\xff\xfe", "not JSON"),
        (b"\x00\x00\x00\x02[]", "not a JSON object"),
        (struct.pack("!I", MAX_HEADER_BYTES + 1) + b"{}", "over"),
        (b"\xff\xff\xff\xff" + b"{}", "over"),
    ],
)
def test_bad_frames_are_refused_with_the_reason(data: bytes, message: str) -> None:
    with pytest.raises(FrameError, match=message):
        decode_frame(data)
    assert frame_time(data) is None


def test_deep_or_huge_headers_and_frames_are_refused_both_ways() -> None:
    deep = "[" * (MAX_DEPTH + 1) + "]" * (MAX_DEPTH + 1)
    raw = ('{"a":' + deep + "}").encode()
    with pytest.raises(FrameError, match="deeper"):
        decode_frame(struct.pack("!I", len(raw)) + raw)
    tricky = b'{"a":"[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[\\""}'  # brackets inside a string are text
    assert decode_frame(struct.pack("!I", len(tricky)) + tricky)[0]["a"].startswith("[[")
    nested: dict = {}
    for _ in range(MAX_DEPTH + 1):
        nested = {"n": nested}
    with pytest.raises(FrameError, match="deeper"):
        encode_frame(nested, JPEG)
    with pytest.raises(FrameError, match="over"):
        encode_frame({"x": "y" * MAX_HEADER_BYTES}, JPEG)
    with pytest.raises(FrameError, match="over"):
        encode_frame({}, bytes(MAX_FRAME_BYTES))
    with pytest.raises(FrameError, match="over"):
        decode_frame(bytes(MAX_FRAME_BYTES + 1))
    with pytest.raises(FrameError, match="JSON object"):
        encode_frame([1], JPEG)  # type: ignore[arg-type]
    assert frame_time(encode_frame({"t": "soon"}, JPEG)) is None


def test_the_header_depth_fast_path_agrees_with_the_byte_walk() -> None:
    """Every reader runs the depth check on every frame, so the usual header (no escaped quote
    or backslash) takes a fast path; on any text it gives the byte walk's depth: strings with
    brackets, unterminated strings, unbalanced and mismatched brackets, escapes."""
    import random

    from racing.framecodec import _raw_depth, _walk_depth

    cases = [b"", b"{}", b'{"a":[1,{"b":[[]]}]}', b'{"a":"[[[{{{"}', b'{"a":"[[[', b"]]][[",
             b"[}{]", b'"\\"[[["[', b'["\\\\"[', b'{"u":"\\u2713[","v":[[]]}', b"((({[",
             b'"""[']  # fmt: skip
    rng = random.Random(48)
    alphabet = b'[]{}"\\a:,u'
    cases += [bytes(rng.choice(alphabet) for _ in range(rng.randint(0, 40))) for _ in range(20_000)]
    for raw in cases:
        assert _raw_depth(raw) == _walk_depth(raw), raw
    header = {"timing": {"cars": [{"sectors": [1.0, 2.0], "name": "A [x] {y}"}] * 4}, "t": 1.0}
    assert decode_header(encode_frame(header, JPEG))[0] == header
    assert _raw_depth(b'{"a":[[{"b":"]]]]"}]]}') == 4
