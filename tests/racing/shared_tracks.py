"""Where DeepRacer's track files are: the nearest ``shared/tracks`` folder above the tests.

The files live outside the repository (``../shared/tracks`` beside a checkout, one level higher
beside a git worktree); tests that need them skip when none is found.
"""

from __future__ import annotations

from pathlib import Path


def find_shared_tracks() -> Path:
    """The nearest ``shared/tracks`` folder above this file, or the conventional path."""
    here = Path(__file__).resolve()
    for parent in here.parents:
        candidate = parent / "shared" / "tracks"
        if candidate.is_dir():
            return candidate
    return here.parents[2].parent / "shared" / "tracks"


SHARED_TRACKS = find_shared_tracks()
