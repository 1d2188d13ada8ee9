"""The create-model form: every field of DeepRacer's wizard, validated field by field.

The discrete action table is not a Django field: its rows arrive as repeated
``action_steering`` / ``action_speed`` inputs, are kept as typed (strings) for re-rendering and
parsed in :meth:`ModelCreateForm.clean`. Errors about the whole table go on the hidden
``action_space`` field, errors about a row into ``row_errors``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from django import forms
from django.core.validators import RegexValidator

from console import tracks
from console.forms import add_service_error, stop_when_ready_field
from console.race_form import RaceSettingsForm
from racing.actions import (
    DEFAULT_DISCRETE,
    MAX_DISCRETE_ACTIONS,
    MAX_SPEED,
    MIN_DISCRETE_ACTIONS,
    MIN_SPEED,
    ActionSpaceError,
    action_range_error,
    discrete_action_list,
)
from training import services
from training.catalog import (
    BATCH_SIZES,
    DEFAULT_PRESET,
    LEAN,
    LOSS_TYPES,
    NETWORK_LABELS,
    PRESETS,
    RANGES,
    SAC_DEFAULTS,
    HyperparameterError,
    Hyperparameters,
    Preset,
    UnknownPreset,
    example_source,
    parse_hyperparameters,
    preset,
)
from training.conditions_form import (
    RAMP_FIELD,
    add_condition_fields,
    clean_conditions,
    condition_groups,
)
from training.models import MODEL_NAME_RE, Direction

SENSORS = [("FRONT_FACING_CAMERA", "Camera"), ("STEREO_CAMERAS", "Stereo camera")]
LIDARS = [
    ("", "No LIDAR"),
    ("LIDAR", "LIDAR (64 ranges)"),
    ("SECTOR_LIDAR", "Sector LIDAR (8 sectors)"),
    ("DISCRETIZED_SECTOR_LIDAR", "Discretized sector LIDAR (8 × 8)"),
]
ALGORITHMS = [("clipped_ppo", "PPO"), ("sac", "SAC")]
ACTION_SPACE_TYPES = [("discrete", "Discrete"), ("continuous", "Continuous")]
HP_FIELDS = (
    "batch_size", "num_epochs", "lr", "beta_entropy", "sac_alpha", "discount_factor",
    "loss_type", "num_episodes_between_training",
)  # fmt: skip
HP_LABELS = {
    "batch_size": "Gradient descent batch size",
    "num_epochs": "Number of epochs",
    "lr": "Learning rate",
    "beta_entropy": "Entropy",
    "sac_alpha": "SAC alpha (α)",
    "discount_factor": "Discount factor",
    "loss_type": "Loss type",
    "num_episodes_between_training": "Experience episodes between each policy-updating iteration",
}
PPO_ONLY = ("num_epochs", "beta_entropy")
SAC_ONLY = ("sac_alpha",)
_DEFAULTS = Hyperparameters()


def hp_help(key: str) -> str:
    """'Default 64 · one of 32, 64, …' as the form shows it under each hyperparameter."""
    default = getattr(_DEFAULTS, key)
    text = f"Default {default:g}" if isinstance(default, float) else f"Default {default}"
    if key in SAC_DEFAULTS:
        text += f" (SAC: {SAC_DEFAULTS[key]})"
    if key == "batch_size":
        return f"{text} · one of {', '.join(map(str, BATCH_SIZES))}"
    if key == "loss_type":
        return text
    low, high = RANGES[key]
    return f"{text} · {low:g} to {high:g}"


def _float(label: str, low: float, high: float, initial: float, **kw: Any) -> forms.FloatField:
    return forms.FloatField(label=label, min_value=low, max_value=high, initial=initial, **kw)


def preset_initial(chosen: Preset) -> dict[str, Any]:
    """The form's values for a preset: action space, algorithm, network, hyperparameters and
    reward function (what the wizard's "Start from" fills in)."""
    hp = chosen.hyperparameters
    return {
        "start_from": chosen.id,
        "action_space_type": "discrete",
        "algorithm": chosen.algorithm,
        "neural_network": chosen.network,
        **{key: getattr(hp, key) for key in HP_FIELDS},
        "reward_function": example_source(chosen.reward_example),
    }


def preset_rows(chosen: Preset) -> list[tuple[str, str]]:
    """The preset's action table as the form keeps it (typed strings)."""
    return [(f"{a['steering_angle']:g}", f"{a['speed']:g}") for a in chosen.action_space]


class ModelCreateForm(RaceSettingsForm):
    start_from = forms.ChoiceField(
        label="Start from",
        choices=[(p.id, p.label) for p in PRESETS],
        initial=DEFAULT_PRESET,
        required=False,
        help_text="Fills the action space, hyperparameters and reward function; change any.",
    )
    name = forms.CharField(
        max_length=64,
        validators=[RegexValidator(MODEL_NAME_RE, "Use 1-64 letters, digits or hyphens.")],
        help_text="1-64 letters, digits or hyphens; no spaces.",
    )
    description = forms.CharField(
        max_length=255, required=False, widget=forms.Textarea(attrs={"rows": 2})
    )
    track_id = forms.ChoiceField(label="Track", error_messages={"required": "Choose a track."})
    direction = forms.ChoiceField(choices=Direction.choices, initial=Direction.NATIVE)
    extra_track_ids = forms.MultipleChoiceField(
        label="Also train on",
        required=False,
        widget=forms.CheckboxSelectMultiple,
        help_text=(
            "Multi-track training: one model learns several tracks at once, the cars dealt "
            "the tracks in turn, each in the direction above."
        ),
    )
    sensor = forms.ChoiceField(choices=SENSORS, initial="FRONT_FACING_CAMERA")
    lidar = forms.ChoiceField(choices=LIDARS, initial="", required=False, label="LIDAR")
    action_space_type = forms.ChoiceField(choices=ACTION_SPACE_TYPES, initial="discrete")
    action_space = forms.CharField(required=False, widget=forms.HiddenInput)  # carries errors
    gen_max_steering = forms.FloatField(label="Maximum steering angle (°)", min_value=1,
                                        max_value=30, initial=30, required=False)  # fmt: skip
    gen_steering_levels = forms.IntegerField(label="Steering levels", min_value=1, max_value=15,
                                             initial=5, required=False)  # fmt: skip
    gen_max_speed = forms.FloatField(label="Maximum speed (m/s)", min_value=MIN_SPEED,
                                     max_value=MAX_SPEED, initial=1.0, required=False)  # fmt: skip
    gen_speed_levels = forms.IntegerField(label="Speed levels", min_value=1, max_value=10,
                                          initial=2, required=False)  # fmt: skip
    steering_low = _float("Right steering angle (°)", -30, 0, -30, required=False)
    steering_high = _float("Left steering angle (°)", 0, 30, 30, required=False)
    speed_low = _float("Minimum speed (m/s)", MIN_SPEED, MAX_SPEED, 1.0, required=False)
    speed_high = _float("Maximum speed (m/s)", MIN_SPEED, MAX_SPEED, 2.0, required=False)
    algorithm = forms.ChoiceField(choices=ALGORITHMS, initial="clipped_ppo")
    neural_network = forms.ChoiceField(
        label="Neural network", choices=list(NETWORK_LABELS.items()), initial=LEAN
    )
    batch_size = forms.TypedChoiceField(
        choices=[(b, b) for b in BATCH_SIZES], coerce=int, initial=_DEFAULTS.batch_size
    )
    num_epochs = forms.IntegerField(min_value=3, max_value=10, initial=_DEFAULTS.num_epochs)
    lr = _float("Learning rate", *RANGES["lr"], _DEFAULTS.lr)
    beta_entropy = _float("Entropy", *RANGES["beta_entropy"], _DEFAULTS.beta_entropy)
    sac_alpha = _float("SAC alpha", *RANGES["sac_alpha"], _DEFAULTS.sac_alpha)
    discount_factor = _float("Discount factor", *RANGES["discount_factor"],
                             _DEFAULTS.discount_factor)  # fmt: skip
    loss_type = forms.ChoiceField(
        choices=[(t, t.replace("_", " ").capitalize()) for t in LOSS_TYPES],
        initial=_DEFAULTS.loss_type,
    )
    num_episodes_between_training = forms.IntegerField(
        min_value=1, max_value=100, initial=_DEFAULTS.num_episodes_between_training
    )
    reward_function = forms.CharField(
        strip=False,
        widget=forms.Textarea(attrs={"rows": 18, "spellcheck": "false"}),
        initial=example_source,
        error_messages={"required": "Write a reward function."},
    )
    max_minutes = forms.IntegerField(
        label="Maximum time (minutes)", min_value=1, max_value=1440, initial=60,
        help_text="Training stops after this many minutes: 1 to 1440 (24 h).",
    )  # fmt: skip
    stop_when_ready = stop_when_ready_field()

    def __init__(self, *args: Any, action_rows: list[tuple[str, str]] | None = None,
                 **kwargs: Any) -> None:  # fmt: skip
        super().__init__(*args, **kwargs)
        choices = [(r.info.id, r.info.name) for r in tracks.track_rows()]
        self.fields["track_id"].choices = choices
        self.fields["extra_track_ids"].choices = choices
        if choices:
            self.fields["track_id"].initial = choices[0][0]
        for key in HP_FIELDS:
            self.fields[key].label = HP_LABELS[key]
            self.fields[key].help_text = hp_help(key)
        if action_rows is None:
            if self.is_bound:
                action_rows = list(
                    zip(
                        self.data.getlist("action_steering"),
                        self.data.getlist("action_speed"),
                        strict=False,
                    )  # fmt: skip
                )
            else:
                action_rows = [(f"{a['steering_angle']:g}", f"{a['speed']:g}")
                               for a in DEFAULT_DISCRETE]  # fmt: skip
        self.action_rows = action_rows
        self.row_errors: dict[int, str] = {}
        add_condition_fields(self, ramp=True)  # the outside world: off by default

    # ---- the action space
    def _discrete_actions(self) -> list[dict] | None:
        rows, actions = self.action_rows, []
        if not MIN_DISCRETE_ACTIONS <= len(rows) <= MAX_DISCRETE_ACTIONS:
            self.add_error(
                "action_space",
                f"A discrete action space has {MIN_DISCRETE_ACTIONS} to {MAX_DISCRETE_ACTIONS} "
                f"actions; this one has {len(rows)}.",
            )
            return None
        for i, (steer_text, speed_text) in enumerate(rows):
            try:
                action = {"steering_angle": float(steer_text), "speed": float(speed_text)}
            except ValueError:
                self.row_errors[i] = "Steering and speed must be numbers."
                continue
            error = action_range_error(action["steering_angle"], action["speed"])
            if error:
                self.row_errors[i] = error[:1].upper() + error[1:] + "."
            actions.append(action)
        if self.row_errors:
            n = len(self.row_errors)
            self.add_error("action_space", f"{n} action{'s' if n > 1 else ''} need fixing.")
            return None
        return actions

    def _continuous_actions(self, data: dict) -> dict | None:
        keys = ("steering_low", "steering_high", "speed_low", "speed_high")
        for key in keys:
            if data.get(key) is None and key not in self.errors:
                self.add_error(key, "This field is required.")
        if any(key in self.errors for key in keys):
            return None
        if data["steering_low"] >= data["steering_high"]:
            self.add_error("steering_high", "The left angle must be above the right angle.")
            return None
        if data["speed_low"] >= data["speed_high"]:
            self.add_error("speed_high", "The maximum speed must exceed the minimum speed.")
            return None
        return {
            "steering_angle": {"low": data["steering_low"], "high": data["steering_high"]},
            "speed": {"low": data["speed_low"], "high": data["speed_high"]},
        }

    def clean(self) -> dict[str, Any]:
        """The form's own checks (fields, the table's rows); the domain's rules come from
        the services, shown on the field they name."""
        data = super().clean()
        if data.get("sensor"):
            data["sensors"] = [data["sensor"], *([data["lidar"]] if data.get("lidar") else [])]
        if data.get("race_type"):
            self._service_check(lambda: self._race(data))
        kind = data.get("action_space_type")
        if kind == "discrete":
            data["actions"] = self._discrete_actions()
        elif kind == "continuous":
            data["actions"] = self._continuous_actions(data)
        if data.get("algorithm") and not any(k in self.errors for k in HP_FIELDS):
            try:
                hp = parse_hyperparameters(self.hyperparameters(data), data["algorithm"])
                data["hyperparameters"] = hp.to_json()
            except HyperparameterError as exc:
                field = exc.field if exc.field in self.fields else None
                self.add_error(field, str(exc).split(": ", 1)[-1].capitalize())
        if data.get("track_id") and data.get("direction") and "extra_track_ids" not in self.errors:
            extra = [[t, data["direction"]] for t in data.get("extra_track_ids") or ()
                     if t != data["track_id"]]  # fmt: skip
            try:
                data["extra_tracks"] = services.check_extra_tracks(
                    data["track_id"], data["direction"], extra
                )
            except services.ServiceError as exc:
                add_service_error(self, exc.message, "extra_track_ids")
        clean_conditions(self, data)
        if data.get("actions") is not None and "hyperparameters" in data and not self.errors:
            self._service_check(lambda: services.check_model_spec(
                track_id=data["track_id"], direction=data["direction"],
                race_type=data["race_type"], race_config=data.get("race_config"),
                sensors=data["sensors"],
                action_space=data["actions"], algorithm=data["algorithm"],
                neural_network=data["neural_network"],
                hyperparameters=data["hyperparameters"], max_minutes=data["max_minutes"],
                stop_when_ready=data.get("stop_when_ready") or 0,
            ))  # fmt: skip
        return data

    @property
    def condition_groups(self) -> list[dict]:
        """The "Outside world" fieldset, family by family (its template's rows)."""
        return condition_groups(self)

    def conditions_ramp_field(self):
        """The outside world's curriculum field (a model's only)."""
        return self[RAMP_FIELD]

    def _race(self, data: dict) -> None:
        """``race_config``: the race settings the services accept for the race type."""
        data["race_config"] = self.race_config(data)

    def _service_check(self, check: Callable[[], object]) -> None:
        try:
            check()
        except services.ServiceError as exc:
            add_service_error(self, exc.message, exc.field)

    @staticmethod
    def hyperparameters(data: dict) -> dict:
        hp = {key: data[key] for key in HP_FIELDS if data.get(key) is not None}
        if data.get("algorithm") == "sac":
            for key in PPO_ONLY:
                hp.pop(key, None)
        return hp

    # ---- the presets
    @classmethod
    def from_preset(cls, data: Any) -> ModelCreateForm:
        """An unbound form with what was typed, the chosen preset's values over it: the
        "Start from" button posts the form back and lands here. An unknown preset leaves the
        form as typed, with the error on ``start_from``."""
        typed = cls(data)
        try:
            chosen = preset(str(data.get("start_from", "")))
        except UnknownPreset as exc:
            form = cls(initial=data.dict(), action_rows=typed.action_rows)
            form.preset_error = str(exc).capitalize() + "."
            return form
        initial = {**data.dict(), **preset_initial(chosen)}
        return cls(initial=initial, action_rows=preset_rows(chosen))

    preset_error = ""
    presets = PRESETS

    # ---- the generator
    def generated_rows(self) -> tuple[list[tuple[str, str]], str]:
        """Rows from the generator fields, or ``(current rows, error message)``."""
        values = {}
        for key in ("gen_max_steering", "gen_steering_levels", "gen_max_speed",
                    "gen_speed_levels"):  # fmt: skip
            field = self.fields[key]
            try:
                value = field.clean(self.data.get(key))
            except forms.ValidationError as exc:
                return self.action_rows, f"{field.label}: {' '.join(exc.messages)}"
            if value is None:
                return self.action_rows, f"{field.label}: this field is required."
            values[key] = value
        try:
            actions = discrete_action_list(
                values["gen_max_steering"], values["gen_steering_levels"],
                values["gen_max_speed"], values["gen_speed_levels"],
            )  # fmt: skip
        except ActionSpaceError as exc:
            return self.action_rows, str(exc).capitalize() + "."
        return [(f"{a['steering_angle']:g}", f"{a['speed']:g}") for a in actions], ""
