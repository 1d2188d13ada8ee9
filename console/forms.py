"""Small forms of the console: sign-up, import, clone and evaluate. The create-model form
lives in console/model_form.py."""

from __future__ import annotations

import secrets
from typing import Any

from django import forms
from django.contrib.auth import password_validation
from django.contrib.auth.forms import UserCreationForm
from django.core.cache import cache
from django.core.validators import RegexValidator

from console import tracks
from console.race_form import RaceSettingsForm
from racing.tracks import MAX_TRACK_FILE_BYTES
from training import catalog
from training.errors import ServiceError
from training.models import MODEL_NAME_RE, Direction, RaceType

MAX_IMPORT_BYTES = catalog.MAX_IMPORT_BYTES
"""Largest model archive accepted: the reader's own limit, so the form and it agree."""

_name_field = {
    "max_length": 64,
    "validators": [RegexValidator(MODEL_NAME_RE, "Use 1-64 letters, digits or hyphens.")],
    "help_text": "1-64 letters, digits or hyphens; no spaces.",
}


class SignUpForm(UserCreationForm):
    """Username and password, checked by Django's password validators."""

    class Meta(UserCreationForm.Meta):
        fields = ("username",)

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        # Django's validators describe themselves as a long <ul>; one line says the same.
        rules = [
            str(text).rstrip(".") for text in password_validation.password_validators_help_texts()
        ]
        self.password_rules = "; ".join(r[:1].lower() + r[1:] for r in rules if r)
        self.fields["password1"].help_text = ""
        self.fields["password2"].help_text = "The same password again."


def _track_choices() -> list[tuple[str, str]]:
    return [(r.info.id, r.info.name) for r in tracks.track_rows()]


class ImportForm(forms.Form):
    name = forms.CharField(**_name_field)
    description = forms.CharField(max_length=255, required=False)
    archive = forms.FileField(
        label="Virtual model (.tar.gz)",
        help_text="A virtual model downloaded from Racecraft: model_metadata.json, "
        "hyperparameters.json, reward_function.py and a checkpoint.",
        error_messages={"required": "Choose a model archive to upload."},
    )

    def clean_archive(self) -> Any:
        upload = self.cleaned_data["archive"]
        if upload.size > MAX_IMPORT_BYTES:
            raise forms.ValidationError(
                f"The archive is larger than {MAX_IMPORT_BYTES // 2**20} MB, the most accepted."
            )
        if upload.size == 0:
            raise forms.ValidationError("The archive is empty.")
        return upload


class _UnsentTextInput(forms.TextInput):
    """A text input whose value never comes back in a page (an access key)."""

    def format_value(self, value: Any) -> None:
        return None


class BucketImportForm(forms.Form):
    """A model straight from a DeepRacer-for-Cloud bucket (MinIO or S3). The keys are read for
    this request only: the secret key's input never shows it back (``render_value=False``)."""

    name = forms.CharField(**_name_field)
    description = forms.CharField(max_length=255, required=False)
    endpoint = forms.CharField(
        label="S3 endpoint",
        max_length=255,
        help_text="host:port of the MinIO or S3 server, e.g. s3.amazonaws.com or minio.lan:9000 "
        "(a local or private address only where the operator allows it).",
    )
    bucket = forms.CharField(max_length=63, help_text="DR_LOCAL_S3_BUCKET, e.g. bucket.")
    prefix = forms.CharField(
        label="Model prefix",
        max_length=255,
        required=False,
        help_text="DR_LOCAL_S3_MODEL_PREFIX, e.g. rl-deepracer-sagemaker: the folder holding "
        "model/, ip/ and reward_function.py. Its logs are not read.",
    )
    access_key = forms.CharField(
        label="Access key", max_length=128, widget=_UnsentTextInput(attrs={"autocomplete": "off"})
    )
    secret_key = forms.CharField(
        label="Secret key",
        max_length=128,
        strip=False,
        widget=forms.PasswordInput(attrs={"autocomplete": "off"}, render_value=False),
        help_text="Used for this import only; never stored.",
    )
    secure = forms.BooleanField(label="Use HTTPS", required=False)


def stop_when_ready_field() -> forms.IntegerField:
    """The "stop when ready" stop condition, as the create and clone pages ask for it (empty:
    off)."""
    return forms.IntegerField(
        label="Stop when ready (evaluations in a row)", min_value=0, max_value=20, initial=0,
        required=False,
        help_text=(
            "Training also stops once this many evaluations in a row complete every lap, and "
            "the model keeps the checkpoint that completed them: 0 to 20, 0 for the time "
            "limit alone."
        ),
    )  # fmt: skip


class CloneForm(forms.Form):
    """What a clone may change (DeepRacer): name, track, reward function, stop condition."""

    name = forms.CharField(**_name_field)
    description = forms.CharField(max_length=255, required=False)
    track_id = forms.ChoiceField(label="Track")
    direction = forms.ChoiceField(choices=Direction.choices)
    reward_function = forms.CharField(
        strip=False,
        widget=forms.Textarea(attrs={"rows": 18, "spellcheck": "false"}),
        error_messages={"required": "Write a reward function."},
    )
    max_minutes = forms.IntegerField(label="Maximum time (minutes)", min_value=1, max_value=1440)
    stop_when_ready = stop_when_ready_field()

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.fields["track_id"].choices = _track_choices()


KEPT_TRACK_S = 3600
"""How long a previewed track file waits on the server for its Import, seconds."""
_KEPT_TRACK_KEY = "track-upload:{user_id}"


def track_upload_keep(*, user_id: int, data: bytes, filename: str) -> str:
    """Keep a previewed track file on the server (Django's cache: Redis, shared by every web
    process) for :data:`KEPT_TRACK_S`, so Import does not send it again; returns the token the
    page carries instead of the file. One kept file per user: a new preview replaces it, so a
    user holds at most one track file's size (MAX_TRACK_FILE_BYTES) there."""
    token = secrets.token_urlsafe(16)
    kept = {"token": token, "data": data, "filename": filename}
    cache.set(_KEPT_TRACK_KEY.format(user_id=user_id), kept, KEPT_TRACK_S)
    return token


def track_upload_forget(*, user_id: int) -> None:
    cache.delete(_KEPT_TRACK_KEY.format(user_id=user_id))


class TrackUploadForm(forms.Form):
    """A DeepRacer ``.npy`` track file of at most MAX_TRACK_FILE_BYTES. After a preview the
    file waits on the server (:func:`track_upload_keep`) and the page carries only its token in
    ``kept``: sent back in the form, a 2 MB file would be 2.7 MB of base64, over Django's
    limit on a request's fields (DATA_UPLOAD_MAX_MEMORY_SIZE, 2.5 MiB): Import answered 400.
    """

    max_size = f"{MAX_TRACK_FILE_BYTES / 1_000_000:g} MB"
    """The limit in words, for the page."""

    file = forms.FileField(label="Track file (.npy)", required=False,
                           widget=forms.ClearableFileInput(attrs={"accept": ".npy"}))  # fmt: skip
    track_id = forms.CharField(
        label="Track id", max_length=64, required=False,
        help_text="Letters, digits, '_' or '-'; default: the file's name.",
    )  # fmt: skip
    name = forms.CharField(label="Display name", max_length=80, required=False)
    kept = forms.CharField(widget=forms.HiddenInput, required=False, max_length=64)
    filename = forms.CharField(widget=forms.HiddenInput, required=False, max_length=255)

    def __init__(self, *args: Any, user_id: int | None = None, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.user_id = user_id
        self._kept: tuple[bytes, str] = (b"", "")

    def clean(self) -> dict[str, Any]:
        cleaned = super().clean()
        token = cleaned.get("kept")
        if cleaned.get("file") or not token:
            return cleaned
        kept = None
        if self.user_id is not None:
            kept = cache.get(_KEPT_TRACK_KEY.format(user_id=self.user_id))
        if not kept or not secrets.compare_digest(kept["token"], token):
            self.add_error("file", "The checked file is no longer kept (an hour after its "
                           "preview, or after another preview): choose it again.")  # fmt: skip
        else:
            self._kept = (kept["data"], kept["filename"])
        return cleaned

    def upload(self) -> tuple[bytes, str]:
        """The file's bytes and name: the new upload, else the one kept from the preview.
        At most one byte over the limit is read, enough for the services to refuse it."""
        upload = self.cleaned_data.get("file")
        if upload:
            return upload.read(MAX_TRACK_FILE_BYTES + 1), upload.name
        return self._kept


class RewardForm(forms.Form):
    """The reward function of a model that has not trained yet."""

    reward_function = forms.CharField(
        strip=False,
        widget=forms.Textarea(attrs={"rows": 18, "spellcheck": "false"}),
        error_messages={"required": "Write a reward function."},
    )


class EvaluateForm(RaceSettingsForm):
    """Where and how to evaluate: track, race (with its boxes or bots), laps, penalties."""

    track_id = forms.ChoiceField(label="Track")
    direction = forms.ChoiceField(choices=Direction.choices, initial=Direction.NATIVE)
    race_type = forms.ChoiceField(
        choices=[("", "The model's own race"), *RaceType.choices], required=False
    )
    laps = forms.TypedChoiceField(
        label="Number of trials", choices=[(n, n) for n in (3, 4, 5)], coerce=int, initial=3
    )
    off_track_penalty_s = forms.FloatField(
        label="Off-track penalty (s)", min_value=0, max_value=60, initial=2.0
    )
    crash_penalty_s = forms.FloatField(
        label="Crash penalty (s)", min_value=0, max_value=60, initial=5.0
    )

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.fields["track_id"].choices = _track_choices()

    def clean(self) -> dict[str, Any]:
        data = super().clean()
        data["race_config"] = None  # no race type: the model's own race and settings
        if data.get("race_type"):
            try:
                data["race_config"] = self.race_config(data)
            except ServiceError as exc:
                add_service_error(self, exc.message, exc.field)
        return data


def add_service_error(form: forms.Form, message: str, field: str | None) -> None:
    """Show a ServiceError on its field when the form has it, else above the form."""
    aliases = {"sensors": "sensor", "archive": "archive", "checkpoint": None}
    field = aliases.get(field, field) if field else None
    form.add_error(field if field in form.fields else None, message[:1].upper() + message[1:])
