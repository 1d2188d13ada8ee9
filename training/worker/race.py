"""A head-to-head race of stored models, run here: their checkpoints from the store (trained
here or imported, AWS-era models included), the track from the catalogue (imported tracks
synced from the database first), then :func:`training.rl.race.run_race`.

A model that cannot race (no trained checkpoint, a file missing from the store, weights that do
not load) still takes its grid slot and is out from the start with the reason."""

from __future__ import annotations

from collections.abc import Sequence

from racing.headtohead import Racer
from racing.race import RaceConfig
from racing.track import Track
from training.models import RacingModel
from training.rl.algorithms import set_torch_threads
from training.rl.checkpoints import CheckpointError, load_checkpoint
from training.rl.evaluation import sb3_policy
from training.rl.race import RaceEntry, RaceReport, RaceSettings, run_race
from training.services import model_metadata, track_catalog, tracks_sync_for
from training.storage import StoreError
from training.store import get_store, keys_for


def race_entry(model: RacingModel) -> RaceEntry:
    """The model's car: its sensors, action space and policy (``unavailable`` when its
    checkpoint cannot be had)."""
    racer = Racer(sensors=tuple(model.sensors), action_space=model.action_space, name=model.name)
    entry = RaceEntry(key=model.pk, name=model.name, racer=racer)
    if not model.has_checkpoint:
        entry.unavailable = "it has no trained checkpoint"
        return entry
    try:
        data = get_store().get_bytes(keys_for(model.pk).best)
        entry.policy = sb3_policy(load_checkpoint(data, model_metadata(model)))
    except (CheckpointError, StoreError, KeyError, FileNotFoundError) as exc:
        entry.unavailable = f"its checkpoint cannot be loaded: {exc}"
    return entry


def race_track(track_id: str, direction: str) -> Track:
    """The track in its driving direction (an imported one synced to this machine first)."""
    tracks_sync_for([track_id])
    return track_catalog().load(track_id).in_direction(direction)


def race_models(
    models: Sequence[RacingModel],
    *,
    track_id: str,
    direction: str,
    settings: RaceSettings,
    race: RaceConfig | None = None,
    title: str = "",
    **hooks,
) -> RaceReport:
    """Race ``models`` (2-4, in entry order) here; ``hooks`` go to :func:`run_race`."""
    set_torch_threads(1)  # one observation per car and step: a second thread only waits
    entries = [race_entry(model) for model in models]
    track = race_track(track_id, direction)
    return run_race(entries, track, settings, race=race, title=title, **hooks)
