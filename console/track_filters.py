"""The Tracks page's search and filters: a GET form (a filtered gallery is a page to link to),
read into :class:`console.tracks.TrackFilter`. The pickers filter the same way in the browser
(static/js/track_filter.js) over the same data attributes."""

from __future__ import annotations

from typing import Any

from django import forms

from console import tracks


def _metres(label: str) -> forms.FloatField:
    widget = forms.NumberInput(attrs={"step": "any", "inputmode": "decimal"})
    return forms.FloatField(label=label, required=False, min_value=0, max_value=1000, widget=widget)


class TrackFilterForm(forms.Form):
    """Search by name or id; filter by season, direction, source, length and width (metres)."""

    q = forms.CharField(
        label="Search",
        required=False,
        max_length=100,
        widget=forms.TextInput(attrs={"type": "search", "placeholder": "Name or id"}),
    )
    season = forms.ChoiceField(label="Season", required=False)
    direction = forms.ChoiceField(
        label="Direction",
        required=False,
        choices=[("", "Any"), *tracks.DIRECTION_LABELS.items()],
    )
    source = forms.ChoiceField(
        label="Source", required=False, choices=[("", "Any"), *tracks.SOURCE_LABELS.items()]
    )
    min_length = _metres("Length from (m)")
    max_length = _metres("Length to (m)")
    min_width = _metres("Width from (m)")
    max_width = _metres("Width to (m)")

    def __init__(self, *args: Any, rows: list[tracks.TrackRow], **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.fields["season"].choices = [("", "Any"), *tracks.track_seasons(rows)]

    @property
    def active(self) -> bool:
        """Whether the form was sent with a filter that narrows the list."""
        return (
            self.is_bound
            and self.is_valid()
            and any(v not in ("", None) for v in self.cleaned_data.values())
        )

    def track_filter(self) -> tracks.TrackFilter | None:
        """The filter the form asks for; None when unbound or invalid (then nothing is
        filtered and the form shows its errors)."""
        if not self.is_bound or not self.is_valid():
            return None
        data = self.cleaned_data
        return tracks.TrackFilter(
            query=data["q"].strip(),
            season=data["season"],
            direction=data["direction"],
            source=data["source"],
            min_length_m=data["min_length"],
            max_length_m=data["max_length"],
            min_width_m=data["min_width"],
            max_width_m=data["max_width"],
        )
