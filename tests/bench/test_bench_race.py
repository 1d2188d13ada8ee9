"""bench/bench_race.py: its bookkeeping (a viewer's window, gaps and delays, the race clock read
off a frame message, the last line), and the whole bench with tiny settings (5 viewers, 3 s of
race clock) through its real daphne, Redis and websockets: the last line's keys are there and
sane. No timing target is asserted: the figures depend on the machine."""

from __future__ import annotations

import subprocess
import sys

import pytest

from tests.bench.loader import BENCH, load_bench


@pytest.fixture(scope="module")
def bench():
    with load_bench("bench_race") as module:
        yield module


def test_a_viewer_window_counts_its_frames_gaps_and_delays(bench) -> None:
    shown_at = {0.07: 10.0, 0.13: 11.0, 0.2: 11.5, 0.27: 12.0}
    arrivals = [(10.05, 0.07), (11.2, 0.13), (11.6, 0.2), (12.1, 0.27)]
    viewer = bench.viewer_window(arrivals, 11.0, 13.0, shown_at)
    assert (viewer.frames, viewer.received) == (3, 4)
    assert viewer.fps == pytest.approx(1.5)
    # From the frame before the window to the first inside it: 1.15 s; the end's gap is 0.9 s.
    assert viewer.max_gap_s == pytest.approx(1.15)
    # Delays of the frames shown from the window's start on: 0.2, 0.1 and 0.1 s.
    assert viewer.delay_median_s == pytest.approx(0.1)
    assert viewer.delay_max_s == pytest.approx(0.2)


def test_a_viewer_that_got_nothing_has_one_gap_the_whole_window(bench) -> None:
    viewer = bench.viewer_window([], 5.0, 7.5, {})
    assert (viewer.frames, viewer.fps, viewer.max_gap_s) == (0, 0.0, pytest.approx(2.5))
    assert viewer.delay_max_s != viewer.delay_max_s  # nan: no delay known


def test_the_race_clock_is_read_off_a_frame_message(bench) -> None:
    from racing.framecodec import encode_frame

    timing = {"clock_s": 12.47, "laps": 10, "over": False, "cars": []}
    payload = encode_frame({"timing": timing, "t": 1_700_000_000.0}, b"\xff\xd8" + b"J" * 50_000)
    assert bench.race_clock(payload) == pytest.approx(12.47)
    assert bench.race_clock(b"\x00\x00\x00\x09not json!") is None
    assert bench.race_clock(b"") is None


def race(bench, seed: int, steps_per_s: float, cpu_s: float, live=None):
    return bench.Race(seed=seed, steps=450, clock_s=30.0, wall_s=450 / steps_per_s,
                      stepping_s=449 / steps_per_s, cpu_s=cpu_s, cars=["racing"], car_steps=900,
                      live=live)  # fmt: skip


def test_the_last_line_has_the_issue_s_keys_and_the_ratio_to_the_unpaced_race(bench) -> None:
    shown = [(round(i / 15, 2), 100.0 + i / 15) for i in range(450)]
    arrivals = [[(t + 0.05, c) for c, t in shown] for _ in range(3)]
    live = bench.live_result(arrivals, shown, shown[-1][1] + 0.01, wanted=4, encodes=450,
                             sent=450)  # fmt: skip
    assert live.connected == 3 and live.frames == 450
    assert live.paced_fps == pytest.approx(15.0)
    assert live.delay_s == pytest.approx(0.05)
    pairs = [(race(bench, 0, 90.0, 4.5), race(bench, 0, 15.0, 18.0, live))]
    values = dict(pair.split("=") for pair in bench.last_line(pairs, 4).split())
    assert float(values["race_fps"]) == pytest.approx(15.0, abs=0.1)
    assert float(values["max_gap_s"]) == pytest.approx(1 / 15, abs=0.01)
    assert values["encodes_per_frame"] == "1.000"
    assert values["sim_steps_per_s"] == "90.0"
    assert values["ratio"] == "4.00"  # 40 ms of CPU a step live, 10 ms unpaced
    assert values["spectators"] == "3/4" and values["seeds"] == "1"
    assert values["retried"] == "0"  # viewers that connected only after a failed try


@pytest.mark.slow
def test_the_bench_runs_with_tiny_settings_and_ends_with_its_key_figures() -> None:
    out = subprocess.run(
        [sys.executable, str(BENCH / "bench_race.py"), "--spectators", "5", "--seconds", "3"],
        capture_output=True, text=True, timeout=400, check=False,
    )  # fmt: skip
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    last = out.stdout.strip().splitlines()[-1]
    values = dict(pair.split("=", 1) for pair in last.split())
    for key in ("race_fps", "paced_fps", "max_gap_s", "encodes_per_frame", "sim_steps_per_s",
                "realtime", "ratio", "delay_s", "frames_per_viewer"):  # fmt: skip
        assert key in values, last
    assert values["spectators"] == "5/5", last
    assert 0.95 <= float(values["encodes_per_frame"]) <= 1.05, last
    assert float(values["frames_per_viewer"]) > 0, last
    assert float(values["race_fps"]) > 0 and float(values["sim_steps_per_s"]) > 0, last
    assert "the same race unpaced and live (steps, each car's outcome): yes" in out.stdout


def test_a_viewer_reads_every_message_however_the_socket_cuts_the_bytes(bench) -> None:
    """The bench's viewer parses messages where the socket put them (``recv_into`` its buffer):
    whatever the reads' sizes, each whole frame message is timed and its race clock read,
    fragments joined, daphne's pings answered; a refused handshake fails the connection."""
    import asyncio

    from racing.framecodec import encode_frame

    class Transport:
        def __init__(self) -> None:
            self.written: list[bytes] = []
            self.closed = False

        def write(self, data: bytes) -> None:
            self.written.append(data)

        def close(self) -> None:
            self.closed = True

    def message(opcode: int, payload: bytes, fin: bool = True) -> bytes:
        n = len(payload)
        size = bytes([n]) if n < 126 else (bytes([126]) + n.to_bytes(2, "big") if n < 65536
                                           else bytes([127]) + n.to_bytes(8, "big"))  # fmt: skip
        return bytes([(0x80 if fin else 0) | opcode]) + size + payload

    frames = [encode_frame({"timing": {"clock_s": k / 15}}, b"J" * size)
              for k, size in enumerate([10, 300, 70_000, 2_000_000, 5])]  # fmt: skip
    stream = b"HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\n\r\n"
    stream += message(0x2, frames[0]) + message(0x9, b"hi") + message(0x2, frames[1])
    stream += message(0x2, frames[2]) + message(0x2, frames[3])
    stream += message(0x2, frames[4][:7], fin=False) + message(0x0, frames[4][7:])

    async def feed(chunk_sizes) -> tuple[list, Transport]:
        times: list = []
        protocol = bench.ViewerProtocol(b"GET / HTTP/1.1\r\n\r\n", times)
        transport = Transport()
        protocol.connection_made(transport)
        at, k = 0, 0
        while at < len(stream):
            buffer = protocol.get_buffer(-1)
            n = min(chunk_sizes[k % len(chunk_sizes)], len(buffer), len(stream) - at)
            buffer[:n] = stream[at : at + n]
            protocol.buffer_updated(n)
            at, k = at + n, k + 1
        assert protocol.accepted.done() and protocol.accepted.exception() is None
        return times, transport

    for sizes in ([1, 4093], [3, 7000, 1], [65536], [len(stream)]):
        times, transport = asyncio.run(feed(sizes))
        assert [clock for _, clock in times] == [k / 15 for k in range(5)], sizes
        assert transport.written[0].startswith(b"GET ")
        pong = transport.written[1]
        assert pong[0] == 0x8A and pong[1] == 0x80 | 2  # a masked pong of 2 bytes
        assert bytes(b ^ pong[2 + i % 4] for i, b in enumerate(pong[6:])) == b"hi"

    async def refused() -> BaseException | None:
        protocol = bench.ViewerProtocol(b"GET / HTTP/1.1\r\n\r\n", [])
        protocol.connection_made(Transport())
        buffer = protocol.get_buffer(-1)
        answer = b"HTTP/1.1 403 Forbidden\r\n\r\n"
        buffer[: len(answer)] = answer
        protocol.buffer_updated(len(answer))
        return protocol.accepted.exception()

    assert isinstance(asyncio.run(refused()), ConnectionError)
