"""The "Outside world" fieldset of a form (the create-model wizard, a league event's form): a
checkbox per condition family (off by default) and, per parameter, an optional range anywhere
within its widest (narrower or wider than the training default).

The fields are added to any Django form by :func:`add_condition_fields`; :func:`clean_conditions`
turns what was typed into the stored setting (``cleaned_data["conditions"]``, {} when off) with
each error on the field it is about; :func:`condition_groups` is what the template
(``templates/partials/conditions_fields.html``) draws. Ranges of a family that is off are kept
as typed (the form re-renders them) but not used. The rules are
:mod:`racing.conditions`' (through :mod:`training.services.conditions`)."""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

from django import forms

from racing.conditions import FAMILIES, parameters
from training.errors import ServiceError
from training.services.conditions import (
    FAMILY_HELP,
    FAMILY_LABELS,
    MAX_RAMP_EPISODES,
    RECOMMENDED_RAMP_EPISODES,
    conditions_build,
    conditions_ramp,
)

_KEY_RE = re.compile(r"\b([a-z]+)\.([a-z_]+)\b")


def toggle_name(family: str) -> str:
    return f"cond_{family}"


def range_names(family: str, name: str) -> tuple[str, str]:
    return f"cond_{family}_{name}_low", f"cond_{family}_{name}_high"


RAMP_FIELD = "cond_ramp_episodes"
"""A model's curriculum (:attr:`racing.conditions.ConditionsSpec.ramp_episodes`); an event's
form has none (every entrant meets the whole conditions from the first race)."""


def add_condition_fields(form: forms.Form, *, ramp: bool = False) -> None:
    """Add the fieldset's fields to ``form`` (call from ``__init__``); ``ramp``: the
    curriculum's field too (a model's form; blank means the recommended one)."""
    if ramp:
        form.fields[RAMP_FIELD] = forms.IntegerField(
            label="Ease them in over (training episodes of each car)", required=False,
            min_value=0, max_value=MAX_RAMP_EPISODES,
            initial=RECOMMENDED_RAMP_EPISODES,
            help_text=(f"Each car's first training episode is the clean world; its conditions "
                       f"grow to their whole ranges by this episode. 0: the whole ranges from "
                       f"the first. Blank: {RECOMMENDED_RAMP_EPISODES}, the recommended "
                       f"curriculum (with it the racing preset trained in fewer steps and "
                       f"coped better in the readiness check than without)."),
            error_messages={
                "min_value": "Ease them in over: 0 or more episodes.",
                "max_value": f"Ease them in over: at most {MAX_RAMP_EPISODES:,} episodes.",
                "invalid": "Ease them in over: a whole number of episodes.",
            },
            widget=forms.NumberInput(attrs={"step": "1",
                                            "placeholder": str(RECOMMENDED_RAMP_EPISODES)}),
        )  # fmt: skip
    for family, params in parameters().items():
        form.fields[toggle_name(family)] = forms.BooleanField(
            label=FAMILY_LABELS.get(family, family), required=False,
            help_text=FAMILY_HELP.get(family, ""),
        )  # fmt: skip
        for name, info in params.items():
            for key, end, default in zip(range_names(family, name), ("low", "high"),
                                         info.default, strict=True):  # fmt: skip
                # What clean_conditions and racing.conditions allow: any range inside the
                # widest, narrower or wider than the training default.
                span = (f"a range may be anything within its widest, {info.low:g} to "
                        f"{info.high:g}, narrower or wider than the default "
                        f"{info.default[0]:g} to {info.default[1]:g}")  # fmt: skip
                form.fields[key] = forms.FloatField(
                    label=f"{info.label}: {end}", required=False,
                    min_value=info.low, max_value=info.high,
                    error_messages={
                        "min_value": f"{info.label}: at least {info.low:g} ({span}).",
                        "max_value": f"{info.label}: at most {info.high:g} ({span}).",
                        "invalid": f"{info.label}: enter a number.",
                    },
                    widget=forms.NumberInput(attrs={"step": "any", "placeholder": f"{default:g}"}),
                )  # fmt: skip


def conditions_initial(stored: Mapping | None) -> dict[str, Any]:
    """The fields' initial values for a stored setting (an event being edited): its families
    on, and the ranges other than the defaults (the training ranges)."""
    initial: dict[str, Any] = {}
    families = (stored or {}).get("families") or {}
    info = parameters()
    for family, params in families.items():
        if family not in info:
            continue
        initial[toggle_name(family)] = True
        for name, bounds in (params or {}).items():
            param = info[family].get(name)
            if param is None or tuple(bounds) == param.default:
                continue
            low_key, high_key = range_names(family, name)
            initial[low_key], initial[high_key] = bounds[0], bounds[1]
    if families:
        initial[RAMP_FIELD] = conditions_ramp(stored)
    return initial


def clean_conditions(form: forms.Form, data: dict) -> None:
    """``data["conditions"]``: the stored setting from the fields ({} when no family is on);
    errors go on the range field they are about, else on the family's checkbox."""
    families = [f for f in FAMILIES if data.get(toggle_name(f))]
    ranges: dict[str, tuple[float, float]] = {}
    bad = False
    for family in families:
        for name, info in parameters()[family].items():
            low_key, high_key = range_names(family, name)
            if low_key in form.errors or high_key in form.errors:
                bad = True
                continue
            low, high = data.get(low_key), data.get(high_key)
            if low is None and high is None:
                continue
            low = info.default[0] if low is None else low  # an end left empty: the default's
            high = info.default[1] if high is None else high
            if low > high:
                form.add_error(high_key, f"{info.label}: the high end must not be below the low "
                                         f"end ({low:g}).")  # fmt: skip
                bad = True
                continue
            ranges[f"{family}.{name}"] = (low, high)
    if bad:
        return
    ramp = 0
    if RAMP_FIELD in form.fields:
        if RAMP_FIELD in form.errors:
            return
        typed = data.get(RAMP_FIELD)
        ramp = RECOMMENDED_RAMP_EPISODES if typed is None else typed
    try:
        data["conditions"] = conditions_build(families, ranges, ramp_episodes=ramp)
    except ServiceError as exc:
        add_conditions_error(form, exc.message, families)


def add_conditions_error(form: forms.Form, message: str, families: list[str] | None = None) -> None:
    """A conditions refusal on the field it names (``family.parameter``), else on the first
    family turned on, else above the form."""
    text = message.removeprefix("conditions: ")
    text = text[:1].upper() + text[1:]
    match = _KEY_RE.search(text)
    if match and match.group(1) in FAMILIES:
        family, name = match.groups()
        key = range_names(family, name)[1]
        form.add_error(key if key in form.fields else toggle_name(family), text)
        return
    on = families if families is not None else [
        f for f in FAMILIES if form.data.get(toggle_name(f))
    ]  # fmt: skip
    form.add_error(toggle_name(on[0]) if on else None, text)


def condition_groups(form: forms.Form) -> list[dict]:
    """Per family, what the template draws: its checkbox and, per parameter, its two range
    fields, the default and widest ranges and the help text; ``open`` when a range was typed
    or is wrong."""
    groups = []
    for family, params in parameters().items():
        rows, typed, errors = [], False, bool(form[toggle_name(family)].errors)
        for name, info in params.items():
            low, high = (form[key] for key in range_names(family, name))
            typed = typed or low.value() not in (None, "") or high.value() not in (None, "")
            errors = errors or bool(low.errors or high.errors)
            unit = f" {info.unit}" if info.unit else ""
            rows.append({"name": name, "label": info.label, "help": info.help, "low": low,
                         "high": high, "widest": f"{info.low:g} to {info.high:g}{unit}",
                         "default": f"{info.default[0]:g} to {info.default[1]:g}{unit}",
                         "errors": [*low.errors, *high.errors]})  # fmt: skip
        groups.append({"family": family, "label": FAMILY_LABELS.get(family, family),
                       "help": FAMILY_HELP.get(family, ""), "toggle": form[toggle_name(family)],
                       "params": rows, "open": typed or errors})  # fmt: skip
    return groups
