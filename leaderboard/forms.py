"""Forms of the league pages: events, submissions and the racer profile. Rules stay in the
services; forms only parse input."""

from __future__ import annotations

import random
from datetime import timedelta

from django import forms
from django.utils import timezone

from leaderboard.models import Division, RacerProfile, RankingMethod, Season
from training.conditions_form import (
    add_condition_fields,
    clean_conditions,
    condition_groups,
    conditions_initial,
)
from training.models import Direction, RaceType, RacingModel
from training.services import track_catalog

DATETIME_FORMAT = "%Y-%m-%dT%H:%M"


def _track_choices() -> list[tuple[str, str]]:
    cat = track_catalog()
    return [(info.id, info.name) for info in cat.list()]


class DateTimeInput(forms.DateTimeInput):
    input_type = "datetime-local"

    def __init__(self) -> None:
        super().__init__(format=DATETIME_FORMAT)


class EventForm(forms.Form):
    """The fields of an event. Facilitators also see season and division (public events);
    racers organising a community race do not."""

    name = forms.CharField(max_length=80)
    description = forms.CharField(widget=forms.Textarea(attrs={"rows": 3}), required=False)
    season = forms.ModelChoiceField(queryset=Season.objects.all(), required=False)
    division = forms.ChoiceField(choices=Division.choices, initial=Division.OPEN)
    track_id = forms.ChoiceField(label="Track")
    direction = forms.ChoiceField(choices=Direction.choices, initial=Direction.NATIVE)
    race_type = forms.ChoiceField(
        choices=RaceType.choices,
        initial=RaceType.TIME_TRIAL,
        help_text="Object avoidance uses the box settings, head-to-bot the bot settings.",
    )
    opens_at = forms.DateTimeField(
        label="Opens (UTC)", widget=DateTimeInput(), input_formats=[DATETIME_FORMAT]
    )
    closes_at = forms.DateTimeField(
        label="Closes (UTC)", widget=DateTimeInput(), input_formats=[DATETIME_FORMAT]
    )
    ranking_method = forms.ChoiceField(choices=RankingMethod.choices)
    min_laps = forms.IntegerField(
        label="Minimum consecutive laps", min_value=1, max_value=5, initial=1
    )
    max_laps = forms.IntegerField(
        label="Maximum laps",
        min_value=1,
        max_value=5,
        initial=3,
        help_text="The evaluation runs this many laps, at least 3.",
    )
    off_track_penalty_s = forms.FloatField(
        label="Off-track penalty (s)", min_value=0, max_value=60, initial=1.0
    )
    collision_penalty_s = forms.FloatField(
        label="Collision penalty (s)", min_value=0, max_value=60, initial=1.0
    )
    max_resets = forms.IntegerField(
        label="Maximum resets", min_value=0, required=False, help_text="Empty: unlimited."
    )
    max_submissions_per_racer = forms.IntegerField(
        label="Submissions per racer", min_value=1, max_value=999, initial=99
    )
    number_of_objects = forms.IntegerField(
        label="Number of boxes", min_value=0, max_value=6, initial=0,
        help_text="Object avoidance: 1 to 6.",
    )  # fmt: skip
    randomize_objects = forms.BooleanField(label="Place boxes at random", required=False)
    bot_count = forms.IntegerField(
        label="Number of bot cars", min_value=0, max_value=6, initial=6,
        help_text="Head-to-bot: 1 to 6 (the 2020 head-to-head qualifying: 6 at 0.75 m/s).",
    )  # fmt: skip
    bot_speed_mps = forms.FloatField(label="Bot speed (m/s)", min_value=0.2, max_value=6.0,
                                     initial=0.75)  # fmt: skip
    bot_lane_changes = forms.BooleanField(required=False)
    bracket_size = forms.TypedChoiceField(
        label="Head-to-head bracket", coerce=int, initial=0, required=False, empty_value=0,
        choices=[(0, "None"), (4, "Top 4"), (8, "Top 8"), (16, "Top 16"), (32, "Top 32")],
        help_text="After qualifying, the best qualifiers race one against one, 1 against the "
        "last, until one is left.",
    )  # fmt: skip
    bracket_laps = forms.IntegerField(label="Laps per bracket race", min_value=1, max_value=10,
                                      initial=2, required=False)  # fmt: skip
    bracket_on_race_day = forms.BooleanField(
        label="Bracket races wait for the race day", required=False,
        help_text="On: each match joins the race-day queue and a facilitator launches it live. "
        "Off: matches run as soon as they are ready.",
    )  # fmt: skip
    live_speed_control = forms.BooleanField(
        label="Live speed control on race day", required=False,
        help_text="On: during their turn, a racer sets their car's speed (0.5×-1.5×) from "
        "their phone, as in DeepRacer's LIVE races.",
    )  # fmt: skip

    conditions_seed = forms.IntegerField(
        label="Conditions seed", min_value=0, max_value=2**31 - 1, required=False,
        help_text="With the outside world on: the seed of its draws, the same for every "
        "entrant (change it for another set of conditions).",
    )  # fmt: skip

    def __init__(self, *args, public: bool, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.fields["track_id"].choices = _track_choices()
        add_condition_fields(self)  # the outside world: off (the clean world) by default
        if isinstance(self.initial.get("conditions"), dict):  # an event being edited
            self.initial.update(conditions_initial(self.initial["conditions"]))
        elif not self.is_bound:  # a new event: its own conditions' seed
            self.initial.setdefault("conditions_seed", random.randrange(2**31))
        if not public:
            del self.fields["season"]
            del self.fields["division"]
        if not self.is_bound and "opens_at" not in self.initial:
            now = timezone.now().replace(second=0, microsecond=0)
            self.initial.setdefault("opens_at", now)
            self.initial.setdefault("closes_at", now + timedelta(days=7))

    def clean_bracket_laps(self) -> int:
        return self.cleaned_data.get("bracket_laps") or 2

    def clean(self) -> dict:
        data = super().clean()
        clean_conditions(self, data)
        return data

    @property
    def condition_groups(self) -> list[dict]:
        return condition_groups(self)

    @property
    def conditions_open(self) -> bool:
        """Whether the page opens the outside-world settings: on, typed into, or wrong."""
        return bool(self["conditions_seed"].errors) or any(
            group["open"] or group["toggle"].value() for group in self.condition_groups
        )

    def event_fields(self) -> dict:
        """The event's fields: the outside-world fieldset becomes ``conditions`` ({}: off)."""
        fields = {k: v for k, v in self.cleaned_data.items() if not k.startswith("cond_")}
        fields["conditions"] = self.cleaned_data.get("conditions", {})
        fields["conditions_seed"] = self.cleaned_data.get("conditions_seed") or 0
        return fields


class SubmitForm(forms.Form):
    model = forms.ModelChoiceField(queryset=RacingModel.objects.none(), empty_label=None)

    def __init__(self, *args, models, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        # Any model id is accepted here; the service says clearly why another racer's model,
        # or one that is not ready, cannot be submitted.
        self.fields["model"].queryset = RacingModel.objects.all()
        self.fields["model"].choices = [(m.pk, m.name) for m in models]


class ProfileForm(forms.Form):
    alias = forms.CharField(
        max_length=32,
        required=False,
        help_text="3-32 letters, digits, - or _. Chosen once: it cannot be changed.",
    )
    country = forms.CharField(max_length=2, required=False, help_text="Two letters, e.g. DE.")
    colour = forms.CharField(
        max_length=7, initial="#ff9f1c", widget=forms.TextInput(attrs={"type": "color"})
    )

    def __init__(self, *args, profile: RacerProfile, **kwargs) -> None:
        kwargs.setdefault(
            "initial",
            {"alias": profile.alias or "", "country": profile.country, "colour": profile.colour},
        )
        super().__init__(*args, **kwargs)
        if profile.alias:
            self.fields["alias"].disabled = True
            self.fields["alias"].help_text = "Your racer alias is fixed."
