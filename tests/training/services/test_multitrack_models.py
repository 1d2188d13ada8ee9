"""Multi-track models: which extra tracks a model may train on (clear messages naming the
field), the reward checked on every track, clones keeping the tracks, one-track models
unchanged."""

from __future__ import annotations

import pytest

from racing.tracks import TrackCatalog
from tests.training.services.factory import create
from training import services
from training.models import RacingModel
from training.services import RewardRejected, ServiceError
from training.services.checks import MAX_TRAINING_TRACKS
from training.services.model_files import training_params
from training.worker.common import env_spec

pytestmark = [pytest.mark.django_db, pytest.mark.usefixtures("store_dir")]


def test_a_model_on_two_tracks_keeps_both_and_its_jobs_drive_both(alice) -> None:
    model = create(alice, extra_tracks=[("racecraft_summit", "cw")])
    assert model.extra_tracks == [["racecraft_summit", "cw"]]
    model.refresh_from_db()
    assert model.training_tracks == [("racecraft_oval", "native"), ("racecraft_summit", "cw")]
    spec = env_spec(model)
    assert spec.tracks == (("racecraft_oval", "native"), ("racecraft_summit", "cw"))
    assert env_spec(model, track_id="racecraft_summit").tracks == ()  # an evaluation: one
    assert 'RACECRAFT_TRACKS: "racecraft_oval:native,racecraft_summit:cw"' in training_params(model)


def test_a_one_track_model_is_as_before(alice) -> None:
    model = create(alice)
    assert model.extra_tracks == [] and env_spec(model).tracks == ()
    assert "RACECRAFT_TRACKS" not in training_params(model)


@pytest.mark.parametrize(
    "extra, message",
    [
        ([("nowhere", "native")], "unknown track 'nowhere' (extra track nowhere)"),
        ([("racecraft_summit", "sideways")], "direction must be native, ccw or cw"),
        ([("racecraft_oval", "native")], "racecraft_oval (native) is chosen twice"),
        ([("racecraft_summit", "cw")] * 2, "racecraft_summit (cw) is chosen twice"),
        ([("racecraft_summit",)], "each extra track is a (track, direction) pair"),
        ("racecraft_summit", "the extra tracks are a list"),
    ],
)
def test_bad_extra_tracks_are_refused_on_their_field(alice, extra, message) -> None:
    with pytest.raises(ServiceError) as caught:
        create(alice, extra_tracks=extra)
    assert message in caught.value.message and caught.value.field == "extra_tracks"
    assert not RacingModel.objects.exists()


def test_at_most_four_tracks(alice) -> None:
    extra = [("racecraft_summit", d) for d in ("native", "cw")] + [
        ("racecraft_technical", d) for d in ("native", "cw")
    ]
    with pytest.raises(ServiceError, match=f"at most {MAX_TRAINING_TRACKS} tracks at once"):
        create(alice, extra_tracks=extra)
    assert create(alice, extra_tracks=extra[:3]).training_tracks[-1] == extra[2]


def test_the_reward_is_checked_on_every_track(alice) -> None:
    only_on_the_oval = (
        "def reward_function(params):\n"
        "    if len(params['waypoints']) > 110:\n"
        "        raise ValueError('not this track')\n"
        "    return 1.0\n"
    )
    catalog = TrackCatalog()
    lengths = {t: len(catalog.load(t).waypoints) for t in ("racecraft_oval", "racecraft_summit")}
    assert lengths["racecraft_oval"] <= 110 < lengths["racecraft_summit"], lengths
    create(alice, name="oval-only", reward_function=only_on_the_oval, validate_reward=True)
    with pytest.raises(RewardRejected):
        create(alice, name="both", reward_function=only_on_the_oval, validate_reward=True,
               extra_tracks=[("racecraft_summit", "native")])  # fmt: skip


def test_a_clone_keeps_the_extra_tracks_but_never_twice(alice) -> None:
    model = create(alice, extra_tracks=[("racecraft_summit", "cw")])
    same = services.model_clone(model=model, owner=alice, name="same")
    assert same.extra_tracks == [["racecraft_summit", "cw"]]
    moved = services.model_clone(model=model, owner=alice, name="moved",
                                 track_id="racecraft_summit", direction="cw")  # fmt: skip
    assert moved.training_tracks == [("racecraft_summit", "cw")]


def test_an_exported_multi_track_model_imports_with_its_tracks(alice, ppo_discrete) -> None:
    from training.interchange.export import checkpoint_bytes
    from training.services.downloads import virtual_model_archive
    from training.store import get_store, keys_for

    model = create(alice, action_space=ppo_discrete.metadata.actions.to_metadata(),
                   extra_tracks=[("racecraft_summit", "cw")])  # fmt: skip
    get_store().put_bytes(keys_for(model.pk).best, checkpoint_bytes(ppo_discrete.model))
    RacingModel.objects.filter(pk=model.pk).update(has_checkpoint=True)
    model.refresh_from_db()
    copy = services.model_import(owner=alice, name="back", upload=virtual_model_archive(model))
    assert copy.training_tracks == model.training_tracks


def test_unknown_or_repeated_imported_tracks_are_left_out() -> None:
    from training.services.model_imports import _imported_extra_tracks

    params = {"RACECRAFT_TRACKS": "racecraft_oval:native,nowhere:cw,racecraft_summit,"
              "racecraft_summit:native,racecraft_technical:sideways"}  # fmt: skip
    assert _imported_extra_tracks(params, "racecraft_oval", "native") == [
        ["racecraft_summit", "native"]
    ]
    assert _imported_extra_tracks({}, "racecraft_oval", "native") == []
