"""Which "action" a logged step counts as in the action charts (the action heatmap, action
usage per iteration and per track section).

A discrete action space counts the chosen action's index. A continuous one has no index (its
sim-trace ``action`` column is ``[steer speed]``), so its steps are binned on a grid over the
space's ranges: :data:`STEERING_BINS` steering bins × :data:`SPEED_BINS` speed bins, listed
steering-major from the right (negative steering) as DeepRacer's action generator lists
discrete actions. Steps are binned by the executed steering (degrees) and speed (m/s) that
the sim-trace's ``steer`` and ``throttle`` columns hold; values outside the ranges count in
the border bins.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

from racing.actions import ActionSpaceError, ActionSpec

STEERING_BINS = 5
"""Continuous spaces: steering bins over the space's steering range."""
SPEED_BINS = 3
"""Continuous spaces: speed bins over the space's speed range."""


@dataclass(frozen=True)
class ActionBins:
    """The bins of the action charts: ``names`` (one per bin) and, for a continuous space,
    its ``steering`` and ``speed`` ranges (``(low, high)``, degrees and m/s)."""

    names: tuple[str, ...]
    steering: tuple[float, float] | None = None
    speed: tuple[float, float] | None = None

    @classmethod
    def for_action_space(cls, definition: list | dict | None) -> ActionBins:
        """The bins of a ``model_metadata.json`` action space; no bins for one that cannot
        be read (the action charts are then empty, the rest of the analysis still works)."""
        try:
            spec = ActionSpec.parse(definition)
        except ActionSpaceError:
            return cls(names=())
        if spec.kind == "discrete":
            return cls(names=tuple(f"{a:g}° {v:g} m/s" for a, v in spec.actions))
        steer_edges = np.linspace(*spec.steering_range, STEERING_BINS + 1)
        speed_edges = np.linspace(*spec.speed_range, SPEED_BINS + 1)
        names = tuple(
            f"{steer_edges[i]:.0f}..{steer_edges[i + 1]:.0f}° "
            f"{speed_edges[j]:.2f}..{speed_edges[j + 1]:.2f} m/s"
            for i in range(STEERING_BINS)
            for j in range(SPEED_BINS)
        )
        return cls(names=names, steering=spec.steering_range, speed=spec.speed_range)

    @property
    def continuous(self) -> bool:
        return self.steering is not None

    def __len__(self) -> int:
        return len(self.names)

    def index(self, action: np.ndarray, steer: np.ndarray, speed: np.ndarray) -> np.ndarray:
        """Each step's bin (int64), -1 where it has none (an index outside a discrete space).

        ``action``: the sim-trace's action index (any value for a continuous space);
        ``steer`` degrees and ``speed`` m/s: what the car executed.
        """
        if not self.continuous:
            index = np.asarray(action).astype(np.int64)
            return np.where((index >= 0) & (index < len(self.names)), index, -1)
        i = _bin(steer, self.steering, STEERING_BINS)
        j = _bin(speed, self.speed, SPEED_BINS)
        return i * SPEED_BINS + j

    def key(self) -> str:
        """What identifies the binning (a summary made with other bins is not reused)."""
        return json.dumps([list(self.names), self.steering, self.speed])


def _bin(values: np.ndarray, bounds: tuple[float, float] | None, bins: int) -> np.ndarray:
    low, high = bounds or (0.0, 1.0)
    scaled = (np.asarray(values, dtype=np.float64) - low) / (high - low) * bins
    return np.clip(np.floor(np.nan_to_num(scaled)), 0, bins - 1).astype(np.int64)
