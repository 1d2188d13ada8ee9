"""The outside-world setting (issue 51): a model trains, and a league event races, under
conditions drawn each episode from named families (:mod:`racing.conditions`). Off by default:
an empty dict is the clean world.

What is stored (``RacingModel.conditions``, ``Event.conditions``, ``EvaluationJob.conditions``)
is :meth:`racing.conditions.ConditionsSpec.to_dict`: ``{"families": {family: {param: [lo,
hi]}}}``. Every way in (the wizard, the command line, the JSON API, an imported archive, an
event form) goes through :func:`conditions_check` or :func:`conditions_build`, which answer a bad
value with a :class:`ServiceError` naming what is wrong.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping

import numpy as np

from racing.conditions import (
    FAMILIES,
    Conditions,
    ConditionsError,
    ConditionsSpec,
    parameters,
)
from racing.conditions import MAX_RAMP_EPISODES as MAX_RAMP_EPISODES  # for forms, commands
from racing.conditions import RECOMMENDED_RAMP_EPISODES as RECOMMENDED_RAMP_EPISODES
from training.errors import ServiceError

FAMILY_LABELS = {
    "light": "Light",
    "look": "The track's look",
    "camera": "Camera",
    "car": "The car",
    "latency": "Latency",
}
FAMILY_HELP = {
    "light": "The room's lighting: brightness, contrast, gamma and a colour cast (a window, "
    "a warm lamp, a dim hall).",
    "look": "What the track looks like: surface and line colours and textures, and the world "
    "beyond the borders (a carpet, tape, a busy room).",
    "camera": "The car's camera: noise, blur, exposure and a mount a little off true.",
    "car": "The car itself: a steering offset and gain, a speed scale (a car that pulls to "
    "one side, a battery that runs down).",
    "latency": "The action applies one or two frames late (a busy compute module).",
}


def conditions_check(value: object, *, field: str = "conditions") -> dict:
    """The stored form of ``value`` (a :class:`ConditionsSpec`, its dict, or empty/None for
    off), validated: ``{}`` when off. Raises :class:`ServiceError` on ``field`` with the
    reason (an unknown family or parameter, a range outside the widest one, ...)."""
    if value is None or value == {} or value == "":
        return {}
    if isinstance(value, ConditionsSpec):
        spec = value
    elif isinstance(value, Mapping):
        try:
            spec = ConditionsSpec.from_dict(dict(value))
        except ConditionsError as exc:
            raise ServiceError(f"conditions: {exc}", field=field) from None
    else:
        raise ServiceError("conditions must be an object of families and their ranges", field=field)
    data = spec.to_dict()
    return data if data.get("families") else {}


def conditions_build(
    families: Iterable[str],
    ranges: Mapping[str, tuple[float, float] | list[float]] | None = None,
    *,
    field: str = "conditions",
    ramp_episodes: int = 0,
) -> dict:
    """The stored form of the families named (each at its training ranges), set by
    ``ranges`` (``"family.parameter"`` → ``(low, high)``), eased in over each car's first
    ``ramp_episodes`` training episodes (a curriculum, :attr:`ConditionsSpec.ramp_episodes`;
    0: none; a model's setting takes :data:`RECOMMENDED_RAMP_EPISODES` by default, an event's
    none); ``{}`` when no family is named. Raises :class:`ServiceError` naming a family or
    parameter that does not exist, or a parameter of a family that is not on."""
    chosen = [f.strip() for f in families if f and f.strip()]
    unknown = [f for f in chosen if f not in FAMILIES]
    if unknown:
        raise ServiceError(
            f"no condition family {unknown[0]!r}; the families are {', '.join(FAMILIES)}",
            field=field,
        )
    ranges = dict(ranges or {})
    if not chosen and not ranges:
        return {}
    spec = ConditionsSpec.default(families=tuple(f for f in FAMILIES if f in chosen))
    try:
        data = spec.with_ramp(ramp_episodes).to_dict()
    except ConditionsError as exc:
        raise ServiceError(f"conditions: {exc}", field=field) from None
    info = parameters()
    for key, bounds in ranges.items():
        family, _, name = key.partition(".")
        if family not in info or name not in info[family]:
            raise ServiceError(f"no condition parameter {key!r}", field=field)
        if family not in chosen:
            raise ServiceError(
                f"{key}: turn on the family {family!r} to narrow its ranges", field=field
            )
        low, high = bounds
        data["families"][family][name] = [float(low), float(high)]
    return conditions_check(data, field=field)


def conditions_draw(value: Mapping | None, seed: int) -> dict:
    """One draw of a stored setting from ``seed`` (``Conditions.to_dict()``: every family and
    parameter), the same for the same setting and seed; ``{}`` when off. A league event's races
    drive in its draw (every car's camera the same)."""
    stored = conditions_check(value)
    if not stored:
        return {}
    return ConditionsSpec.from_dict(stored).sample(np.random.default_rng([int(seed)])).to_dict()


def conditions_drawn_check(value: object, *, field: str = "conditions") -> dict:
    """A drawn set of conditions (:meth:`Conditions.to_dict` form) validated; ``{}`` for none
    or the clean world. Raises :class:`ServiceError` on ``field``."""
    if not value:
        return {}
    try:
        drawn = Conditions.from_dict(value)  # type: ignore[arg-type]
    except ConditionsError as exc:
        raise ServiceError(f"conditions: {exc}", field=field) from None
    return {} if drawn.is_clean else drawn.to_dict()


def conditions_summary(value: Mapping | None) -> list[dict]:
    """What a page shows of a stored setting, per family on: ``{"family", "label", "ranges"}``,
    ``ranges`` the parameters set apart from their default (training) range as ``(label,
    "0.8 to 1.2 unit")`` (empty: every parameter at its default); an empty list when off."""
    families = (value or {}).get("families") or {}
    info = parameters()
    rows = []
    for family in FAMILIES:
        if family not in families:
            continue
        ranges = []
        for name, bounds in (families[family] or {}).items():
            param = info.get(family, {}).get(name)
            try:
                low, high = float(bounds[0]), float(bounds[1])
            except (TypeError, ValueError, IndexError):
                continue
            if param is not None and (low, high) == param.default:
                continue
            label = param.label if param is not None else name
            unit = f" {param.unit}" if param is not None and param.unit else ""
            text = f"{low:g}{unit}" if low == high else f"{low:g} to {high:g}{unit}"
            ranges.append((label, text))
        rows.append({"family": family, "label": FAMILY_LABELS.get(family, family),
                     "ranges": ranges})  # fmt: skip
    return rows


def conditions_ramp(value: Mapping | None) -> int:
    """A stored setting's curriculum: the training episodes of each car over which its
    conditions grow to their whole ranges (0: none, full strength from the first)."""
    try:
        return max(0, int((value or {}).get("ramp_episodes") or 0))
    except (TypeError, ValueError):
        return 0


def conditions_families(value: Mapping | None) -> list[str]:
    """The families a stored setting turns on, in :data:`FAMILIES` order."""
    families = (value or {}).get("families") or {}
    return [f for f in FAMILIES if f in families]


# ---- training_params.yaml: one flat key, which DeepRacer's tools ignore
PARAMS_KEY = "RACECRAFT_CONDITIONS"


def conditions_param(value: Mapping | None) -> str:
    """The setting as one line of JSON for ``training_params.yaml`` ("" when off)."""
    if not value or not value.get("families"):
        return ""
    return json.dumps(dict(value), separators=(",", ":"), sort_keys=True)


def conditions_from_param(text: str) -> dict:
    """The setting read back from :func:`conditions_param`'s line; ``{}`` when absent or not
    valid (an archive's setting that does not validate here is not kept)."""
    if not text:
        return {}
    try:
        return conditions_check(json.loads(text))
    except (ValueError, ServiceError):
        return {}
