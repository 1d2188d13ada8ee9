"""Fixtures for the simulator's tests: real DeepRacer tracks from ../shared/tracks when present."""

from __future__ import annotations

import pytest
from shared_tracks import SHARED_TRACKS

from racing.track import Track


def shared_track(name: str) -> Track:
    path = SHARED_TRACKS / f"{name}.npy"
    if not path.exists():
        pytest.skip(f"{path} is not present (DeepRacer track files live outside the repo)")
    return Track.from_file(path)


@pytest.fixture(scope="session")
def reinvent() -> Track:
    """DeepRacer's re:Invent 2018 track (reinvent_base), native counter-clockwise direction."""
    return shared_track("reinvent_base")


@pytest.fixture(scope="session")
def load_shared():
    """A loader for any file of ../shared/tracks by stem (the test skips when it is absent)."""
    return shared_track
