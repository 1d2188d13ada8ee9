"""Fixtures for the simulator's tests: DeepRacer's tracks, built in (racing/tracks/deepracer/)."""

from __future__ import annotations

import pytest

from racing.track import Track
from racing.tracks import DEEPRACER_DIR


def deepracer_track(name: str) -> Track:
    """The built-in DeepRacer track file ``name`` (its stem); a missing one fails the test."""
    return Track.from_file(DEEPRACER_DIR / f"{name}.npy")


@pytest.fixture(scope="session")
def reinvent() -> Track:
    """DeepRacer's re:Invent 2018 track (reinvent_base), native counter-clockwise direction."""
    return deepracer_track("reinvent_base")


@pytest.fixture(scope="session")
def load_shared():
    """A loader for any built-in DeepRacer track file by stem."""
    return deepracer_track
