"""``{{ event.conditions|conditions_in_words }}``: an event's outside world per family, with its
strength in words (:func:`leaderboard.conditions_words.conditions_in_words`)."""

from __future__ import annotations

from collections.abc import Mapping

from django import template

from leaderboard.conditions_words import FamilyInWords
from leaderboard.conditions_words import conditions_in_words as _in_words

register = template.Library()


@register.filter
def conditions_in_words(value: Mapping | None) -> list[FamilyInWords]:
    return _in_words(value if isinstance(value, Mapping) else None)
