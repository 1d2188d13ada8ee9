"""The example reward functions the console offers: DeepRacer's four, in our words, and the
racing preset's (:mod:`training.rl.presets`), which pays speed along the track, and that one
easing off before bends (docs/benchmarks.md, "Easing off before bends").

The files are data: read them with :func:`example_source`; never import them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

HERE = Path(__file__).resolve().parent


@dataclass(frozen=True)
class RewardExample:
    id: str
    title: str
    race_type: str
    filename: str


EXAMPLES: tuple[RewardExample, ...] = (
    RewardExample(
        "follow_center_line",
        "Time trial - follow the center line (Default)",
        "TIME_TRIAL",
        "follow_center_line.py",
    ),
    RewardExample(
        "stay_inside_borders",
        "Time trial - stay inside the two borders",
        "TIME_TRIAL",
        "stay_inside_borders.py",
    ),
    RewardExample(
        "prevent_zig_zag", "Time trial - prevent zig-zag", "TIME_TRIAL", "prevent_zig_zag.py"
    ),
    RewardExample(
        "object_avoidance",
        "Object avoidance - stay on one lane and not crashing",
        "OBJECT_AVOIDANCE",
        "object_avoidance.py",
    ),
    RewardExample(
        "speed_along_track",
        "Time trial - fast laps: speed along the track (Racing preset)",
        "TIME_TRIAL",
        "speed_along_track.py",
    ),
    RewardExample(
        "speed_along_track_bends",
        "Time trial - fast laps, easing off before bends (fewer steps to a clean lap)",
        "TIME_TRIAL",
        "speed_along_track_bends.py",
    ),
)
DEFAULT_EXAMPLE = "follow_center_line"


def example_source(example_id: str = DEFAULT_EXAMPLE) -> str:
    """Source of an example; KeyError for an unknown id."""
    for example in EXAMPLES:
        if example.id == example_id:
            return (HERE / example.filename).read_text(encoding="utf-8")
    raise KeyError(example_id)
