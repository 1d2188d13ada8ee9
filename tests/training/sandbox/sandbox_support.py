"""Shared helpers of the sandbox tests: realistic params and a check that the host is intact."""

from __future__ import annotations

import os
import threading
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import psutil

TRACK_ID = "racecraft_oval"


def real_params(situation: str = "mid_lap") -> dict[str, Any]:
    """Params built by the simulator when racing.params exists, else a hand-written dict."""
    try:
        from racing.params import scenario_params
        from racing.tracks import TrackCatalog
    except ImportError:  # before racing/params.py landed
        return fallback_params()
    return scenario_params(TrackCatalog().load(TRACK_ID), situation)


def fallback_params() -> dict[str, Any]:
    waypoints = [(float(i), 0.0) for i in range(10)]
    return {
        "all_wheels_on_track": True, "x": 1.5, "y": 0.1, "heading": 0.0, "speed": 1.0,
        "steering_angle": 0.0, "progress": 15.0, "steps": 10, "distance_from_center": 0.1,
        "is_left_of_center": True, "is_offtrack": False, "is_crashed": False,
        "is_reversed": False, "track_width": 1.0, "track_length": 9.0,
        "waypoints": waypoints, "closest_waypoints": [1, 2], "closest_objects": [0, 0],
        "objects_location": [], "objects_distance": [], "objects_left_of_center": [],
        "objects_speed": [], "objects_heading": [], "projection_distance": 1.5,
        "objects_distance_from_center": [], "object_in_camera": False, "sim_time": 0.6,
    }  # fmt: skip


def _target(fd: str) -> str:
    """What descriptor ``fd`` of this process is (a path, ``pipe:[…]``, ``socket:[…]``...), so
    that a leak says what leaked; "closed" when it went meanwhile."""
    try:
        return os.readlink(f"/proc/self/fd/{fd}")
    except OSError:
        return "closed"


def _native_threads() -> dict[str, str]:
    """This process's threads as the kernel sees them (Python's and native libraries' own, such
    as a Rust or gRPC runtime's), id to name."""
    names = {}
    for tid in os.listdir("/proc/self/task"):
        try:
            names[tid] = Path(f"/proc/self/task/{tid}/comm").read_text().strip()
        except OSError:
            continue
    return names


def _leak_report(leaked: dict[str, str], threads_before: dict[str, str]) -> str:
    """The leaked descriptors, and the threads that could have opened them: a descriptor of
    a kind the sandbox's parent side never opens (an eventfd, a socket) has come from another
    library's thread running meanwhile, and its name says which."""
    now = _native_threads()
    new = sorted(name for tid, name in now.items() if tid not in threads_before)
    counts = dict(Counter(now.values()))
    return f"descriptors leaked: {leaked}; threads started meanwhile: {new}; all threads: {counts}"


@contextmanager
def host_intact(*watched_dirs: Path) -> Iterator[None]:
    """Assert that, across the block, no child process, thread or descriptor was left behind
    and no file appeared in or vanished from ``watched_dirs``."""
    me = psutil.Process()
    children = {c.pid for c in me.children(recursive=True)}
    threads = {t.ident for t in threading.enumerate()}
    fds = set(os.listdir("/proc/self/fd"))
    native = _native_threads()
    listings = {d: sorted(os.listdir(d)) for d in watched_dirs}
    yield
    left = [c for c in me.children(recursive=True) if c.pid not in children]
    assert not left, f"processes left behind: {left}"
    assert {t.ident for t in threading.enumerate()} == threads, "threads leaked"
    after = set(os.listdir("/proc/self/fd")) - fds
    leaked = {fd: _target(fd) for fd in after if os.path.exists(f"/proc/self/fd/{fd}")}
    assert not leaked, _leak_report(leaked, native)
    for d, before in listings.items():
        assert sorted(os.listdir(d)) == before, f"files changed in {d}"
