"""An event's outside world in words, for the racer about to submit (and their submission's
page): which families the event turns on and how strong each is.

A family's **strength** is how far its ranges reach from the simulator as it is (each
parameter's neutral value) towards the widest range the readiness check tests: 0 the clean
world, 1 the widest. Its words: *mild* (up to a third of the way), *moderate* (up to two
thirds; a family turned on at its training defaults reaches about half), *strong* (more), and
*at its widest* (all the way). The ranges set apart from the defaults are listed too
(:func:`training.services.conditions.conditions_summary`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TypedDict

from racing.conditions import ParameterInfo, parameters
from training.services.conditions import conditions_summary

MILD, MODERATE = 1 / 3, 2 / 3
"""The strength (0-1) up to which a family reads as mild, then moderate."""


class FamilyInWords(TypedDict):
    family: str
    label: str
    strength: float
    """0-1: the furthest its ranges reach from neutral towards the widest."""
    percent: int
    words: str
    ranges: list[tuple[str, str]]
    """(parameter label, "low to high unit") for the ranges set apart from the defaults."""


def reach(info: ParameterInfo, low: float, high: float) -> float:
    """How far the range ``low..high`` reaches from ``info.neutral`` towards the widest range's
    ends, 0-1 (the further side)."""
    sides = []
    if info.high > info.neutral:
        sides.append((high - info.neutral) / (info.high - info.neutral))
    if info.neutral > info.low:
        sides.append((info.neutral - low) / (info.neutral - info.low))
    return min(1.0, max(0.0, *sides)) if sides else 0.0


def strength_words(strength: float) -> str:
    if strength >= 1.0 - 1e-9:
        return "at its widest"
    if strength <= MILD + 1e-9:
        return "mild"
    return "moderate" if strength <= MODERATE + 1e-9 else "strong"


def conditions_in_words(stored: Mapping | None) -> list[FamilyInWords]:
    """Per family the stored setting turns on (in the families' order): its label, strength,
    strength in words and the ranges set apart from the defaults. Empty when off."""
    families = (stored or {}).get("families") or {}
    info = parameters()
    rows: list[FamilyInWords] = []
    for summary in conditions_summary(stored):
        family = summary["family"]
        strength = 0.0
        for name, bounds in (families.get(family) or {}).items():
            param = info.get(family, {}).get(name)
            if param is None:
                continue
            strength = max(strength, reach(param, float(bounds[0]), float(bounds[1])))
        rows.append(FamilyInWords(
            family=family, label=summary["label"], strength=strength,
            percent=round(100 * strength), words=strength_words(strength),
            ranges=summary["ranges"],
        ))  # fmt: skip
    return rows
