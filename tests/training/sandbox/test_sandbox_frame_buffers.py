"""Issue 52 (kernel layers, part B): a frame's array buffers are decoded once each.

256 array placeholders naming one 32 MB buffer made the parent copy it 256 times. Our own
encoder gives every array a buffer of its own, so a buffer named twice is refused, before any
copy is made. Counted in bytes allocated (tracemalloc's peak around the real decoder), not time.
"""

from __future__ import annotations

import json
import struct
import subprocess
import sys
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from training.sandbox.protocol import ProtocolError, decode, encode

ROOT = Path(__file__).resolve().parents[3]
BUFFER_BYTES = 32_000_000  # a frame under the 32 MiB message limit
NAMES = 256


def hostile_body(names: int = NAMES, size: int = BUFFER_BYTES) -> bytes:
    """A frame body (no length prefix) whose one buffer ``names`` placeholders name."""
    spec = {"__ndarray__": 0, "dtype": "uint8", "shape": [size]}
    header = json.dumps({"m": [spec] * names, "b": [size]}).encode()
    return struct.pack(">I", len(header)) + header + bytes(size)


def _decode_peak(body: bytes) -> tuple[int, object]:
    """Bytes the decoder allocated at its peak, and what it returned or raised."""
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        try:
            outcome: object = decode(body)
        except ProtocolError as exc:
            outcome = exc
        return tracemalloc.get_traced_memory()[1] - base, outcome
    finally:
        tracemalloc.stop()


def test_a_buffer_named_256_times_costs_no_copy() -> None:
    peak, outcome = _decode_peak(hostile_body())
    assert isinstance(outcome, ProtocolError) and "named twice" in str(outcome)
    assert peak < BUFFER_BYTES // 10, peak  # 256 copies before; refused before the first now


def test_one_array_per_buffer_costs_one_copy() -> None:
    """The legitimate frame of the same size: one copy (a writable array of its own)."""
    peak, outcome = _decode_peak(hostile_body(names=1))
    assert isinstance(outcome, list) and outcome[0].nbytes == BUFFER_BYTES
    assert outcome[0].flags.writeable
    assert BUFFER_BYTES <= peak < BUFFER_BYTES * 1.1, peak


def test_what_our_senders_send_still_decodes() -> None:
    """The same array twice in one message travels as two buffers: never refused."""
    frame = np.arange(12, dtype=np.float32).reshape(3, 4)
    message = {"obs": [frame, frame], "mask": np.array([True, False]), "n": np.int64(3)}
    body = encode(message)[4:]
    got = decode(body)
    assert [a.tolist() for a in got["obs"]] == [frame.tolist()] * 2
    assert got["mask"].tolist() == [True, False] and got["n"] == 3
    assert got["obs"][0] is not got["obs"][1]


@pytest.mark.parametrize(
    "spec",
    [
        {"__ndarray__": 1, "dtype": "uint8", "shape": [4]},  # no such buffer
        {"__ndarray__": -1, "dtype": "uint8", "shape": [4]},  # from the end: refused too
        {"__ndarray__": 0, "dtype": "uint8", "shape": [5]},  # more than its bytes
        {"__ndarray__": 0, "dtype": "float64", "shape": [1]},  # a dtype wider than its bytes
    ],
)
def test_a_placeholder_that_does_not_match_its_buffer_is_refused(spec: dict) -> None:
    header = json.dumps({"m": [spec], "b": [4]}).encode()
    with pytest.raises(ProtocolError):
        decode(struct.pack(">I", len(header)) + header + bytes(4))


SCRIPT = r"""
import json, sys, tracemalloc
from training.sandbox import SandboxLimits, evaluate_reward, protocol

peaks = []
real_decode = protocol.decode


def measured(body):
    base = tracemalloc.get_traced_memory()[0]
    tracemalloc.reset_peak()
    try:
        return real_decode(body)
    finally:
        peaks.append(tracemalloc.get_traced_memory()[1] - base)


protocol.decode = measured  # FrameReader.read looks it up in the module at each frame
tracemalloc.start()
result = evaluate_reward(sys.argv[1], [{}], limits=SandboxLimits(per_call_seconds=30.0),
                         python_guards=False)
print(json.dumps({"peaks": peaks, "errors": [e.message for e in result.errors]}))
"""
HOSTILE = """
import gc, json, os, struct

def reward_function(params):
    spec = {"__ndarray__": 0, "dtype": "uint8", "shape": [SIZE]}
    header = json.dumps({"m": [spec] * NAMES, "b": [SIZE]}).encode()
    body = struct.pack(">I", len(header)) + header + bytes(SIZE)
    for o in gc.get_objects():
        if type(o).__name__ == "SandboxContext":
            os.write(o._out, struct.pack(">I", len(body)) + body)
    return 1.0
"""


@pytest.mark.slow
def test_a_sandbox_that_sends_it_costs_the_parent_no_copy() -> None:
    """Through the real sandbox, the guard off: the parent's decoder, measured outside it."""
    source = f"SIZE, NAMES = {BUFFER_BYTES}, {NAMES}\n" + HOSTILE
    out = subprocess.run(
        [sys.executable, "-c", SCRIPT, source],
        capture_output=True, text=True, timeout=300, cwd=ROOT,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr[-2000:]
    report = json.loads(out.stdout.strip().splitlines()[-1])
    (message,) = report["errors"]
    assert "malformed data" in message and "named twice" in message
    assert report["peaks"], "the parent decoded nothing"
    assert max(report["peaks"]) < BUFFER_BYTES // 10, report["peaks"]
