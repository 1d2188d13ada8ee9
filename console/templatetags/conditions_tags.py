"""``{{ model.conditions|conditions_summary }}``: a stored outside-world setting as rows a page
shows (:func:`training.services.conditions.conditions_summary`)."""

from __future__ import annotations

from collections.abc import Mapping

from django import template

from training.services.conditions import conditions_ramp as _ramp
from training.services.conditions import conditions_summary as _summary

register = template.Library()


@register.filter
def conditions_summary(value: Mapping | None) -> list[dict]:
    return _summary(value if isinstance(value, Mapping) else None)


@register.filter
def conditions_ramp(value: Mapping | None) -> int:
    """The setting's curriculum in episodes (0: none)."""
    return _ramp(value if isinstance(value, Mapping) else None)
