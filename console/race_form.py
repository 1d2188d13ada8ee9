"""The race type and its settings, as the create-model wizard and the evaluation form ask them.

The form only asks: :func:`training.services.race_settings` holds the rules (1-6 boxes or bots,
bot speed 0.2-6 m/s, fixed positions, lane-change times) and its errors land on the field they
name. Both forms render the settings with ``templates/models/_race_settings.html``.
"""

from __future__ import annotations

from typing import Any

from django import forms

from training import services
from training.models import Direction, RaceType

PLACEMENTS = [("fixed", "Fixed"), ("random", "Random each episode")]
RACE_FIELDS = (
    "number_of_objects", "object_placement", "object_positions", "number_of_bots", "bot_speed",
    "bot_lane_change", "lane_change_min_s", "lane_change_max_s",
)  # fmt: skip
DEFAULTS = services.RACE_DEFAULTS


class RaceSettingsForm(forms.Form):
    """``race_type`` and the settings of object avoidance and head-to-bot races."""

    race_type = forms.ChoiceField(choices=RaceType.choices, initial=RaceType.TIME_TRIAL)
    number_of_objects = forms.IntegerField(
        label="Number of boxes", initial=DEFAULTS["number_of_objects"], required=False,
        help_text="1 to 6.",
    )  # fmt: skip
    object_placement = forms.ChoiceField(label="Box placement", choices=PLACEMENTS,
                                         initial="fixed", required=False)  # fmt: skip
    object_positions = forms.CharField(
        label="Fixed positions (optional)", required=False, max_length=200,
        help_text="fraction of the lap,lane per box, e.g. 0.25,1;0.5,-1 (lane 1 inner, -1 "
        "outer; 0.07-0.90, at least 0.13 apart). Blank: evenly spaced.",
    )  # fmt: skip
    number_of_bots = forms.IntegerField(
        label="Number of bot cars", initial=DEFAULTS["number_of_bots"], required=False,
        help_text="1 to 6.",
    )  # fmt: skip
    bot_speed = forms.FloatField(
        label="Bot speed (m/s)", initial=DEFAULTS["bot_speed"], required=False,
        help_text="0.2 to 6 m/s.",
    )  # fmt: skip
    bot_lane_change = forms.BooleanField(label="Bots change lanes", required=False)
    lane_change_min_s = forms.FloatField(
        label="Lane change after at least (s)", initial=DEFAULTS["lane_change_min_s"],
        required=False,
    )  # fmt: skip
    lane_change_max_s = forms.FloatField(
        label="Lane change after at most (s)", initial=DEFAULTS["lane_change_max_s"],
        required=False,
    )  # fmt: skip

    def race_config(self, data: dict[str, Any]) -> dict[str, Any]:
        """The race's settings as the services store them; raises ``ServiceError``."""
        race_type = data["race_type"]
        settings: dict[str, Any] = {}

        def value(key: str) -> Any:
            return data[key] if data.get(key) is not None else DEFAULTS[key]

        if race_type == RaceType.OBJECT_AVOIDANCE:
            settings = {
                "number_of_objects": value("number_of_objects"),
                "randomize_objects": data.get("object_placement") == "random",
                "object_positions": services.parse_object_positions(
                    data.get("object_positions") or ""
                ),
            }
        elif race_type == RaceType.HEAD_TO_BOT:
            settings = {
                "number_of_bots": value("number_of_bots"),
                "bot_speed": value("bot_speed"),
                "bot_lane_change": bool(data.get("bot_lane_change")),
                "lane_change_min_s": value("lane_change_min_s"),
                "lane_change_max_s": value("lane_change_max_s"),
            }
        return services.race_settings(race_type, settings)


class RaceLayoutForm(RaceSettingsForm):
    """A race's layout on a track, for its preview (``/tracks/<id>/race.png``): the race
    settings, the driving direction and which random draw to show."""

    direction = forms.ChoiceField(choices=Direction.choices, initial=Direction.NATIVE,
                                  required=False)  # fmt: skip
    seed = forms.IntegerField(
        label="Random draw", min_value=0, max_value=999_999, initial=0, required=False,
        help_text="Which random placement to show, for boxes placed at random.",
    )  # fmt: skip

    def layout(self) -> tuple[str, str, dict[str, Any], int]:
        """``(direction, race_type, race settings, seed)``. Raises ``ServiceError`` naming the
        first bad field, in words."""
        if not self.is_valid():
            name, errors = next(iter(self.errors.items()))
            label = self[name].label if name in self.fields else None
            text = " ".join(str(e) for e in errors)
            raise services.ServiceError(f"{label}: {text}" if label else text, field=name)
        data = self.cleaned_data
        race = self.race_config(data)
        return (
            data.get("direction") or Direction.NATIVE,
            data["race_type"],
            race,
            data.get("seed") or 0,
        )


class TrackLayoutForm(RaceLayoutForm):
    """The Tracks page's layout preview: :class:`RaceLayoutForm` on a chosen track."""

    track = forms.ChoiceField(label="Track", choices=())
    field_order = ["track", "direction", "race_type"]

    def __init__(self, *args: Any, track_choices: list[tuple[str, str]], **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.fields["track"].choices = track_choices
        self.fields["race_type"].initial = RaceType.OBJECT_AVOIDANCE


def race_initial(race_type: str, stored: dict[str, Any] | None) -> dict[str, Any]:
    """Initial values of the race fields for a stored race (a model's own, for evaluations)."""
    stored = stored or {}
    initial: dict[str, Any] = {"race_type": race_type}
    for key in ("number_of_objects", "number_of_bots", "bot_speed", "bot_lane_change",
                "lane_change_min_s", "lane_change_max_s"):  # fmt: skip
        if key in stored:
            initial[key] = stored[key]
    if stored.get("randomize_objects"):
        initial["object_placement"] = "random"
    positions = stored.get("object_positions") or []
    if positions:
        initial["object_positions"] = ";".join(f"{f:g},{lane}" for f, lane in positions)
    return initial
