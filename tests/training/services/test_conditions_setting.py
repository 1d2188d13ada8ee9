"""The outside-world setting of a model (issue 51): validated by the services, copied on clone,
recorded in ``training_params.yaml`` under a key DeepRacer's tools ignore and read back on
import of our own archive."""

from __future__ import annotations

import pytest
from factory import create

from training import services
from training.errors import ServiceError
from training.interchange.export import checkpoint_bytes
from training.models import RacingModel
from training.services.conditions import (
    conditions_build,
    conditions_check,
    conditions_from_param,
    conditions_summary,
)
from training.services.downloads import virtual_model_archive
from training.services.model_files import training_params
from training.services.model_imports import read_training_params
from training.store import get_store, keys_for

pytestmark = [pytest.mark.django_db, pytest.mark.usefixtures("store_dir")]
LIGHT = {"families": {"light": {"brightness": [-20, 20]}, "camera": {}}}


def test_off_by_default_and_stored_canonical(alice) -> None:
    assert create(alice).conditions == {}
    model = create(alice, name="m2", conditions=LIGHT)
    families = model.conditions["families"]
    assert list(families) == ["light", "camera"]
    assert families["light"]["brightness"] == [-20.0, 20.0]
    assert families["light"]["contrast"] == [0.85, 1.2]  # left out: its training range
    assert families["camera"]["noise"] == [0.0, 6.0]
    model.refresh_from_db()
    assert model.conditions["families"]["light"]["brightness"] == [-20.0, 20.0]


@pytest.mark.parametrize(
    ("value", "words"),
    [
        ({"families": {"weather": {}}}, "weather"),
        ({"families": {"light": {"brightness": [-90, 0]}}}, "wider than its widest range"),
        ({"families": {"light": {"glare": [50, 10]}}}, "above high"),
        ({"families": {"light": {"shade": [0, 1]}}}, "shade"),
        ("light", "an object of families"),
    ],
)
def test_bad_settings_are_refused_with_the_reason(alice, value, words) -> None:
    with pytest.raises(ServiceError, match=words) as err:
        create(alice, conditions=value)
    assert err.value.field == "conditions"
    assert not RacingModel.objects.exists()


def test_build_from_families_and_narrowed_ranges() -> None:
    built = conditions_build(["latency", "light"], {"light.gamma": (0.9, 1.1)})
    assert list(built["families"]) == ["light", "latency"]
    assert built["families"]["light"]["gamma"] == [0.9, 1.1]
    assert conditions_build([], {}) == {} == conditions_check(None) == conditions_check({})
    with pytest.raises(ServiceError, match="turn on the family 'camera'"):
        conditions_build(["light"], {"camera.blur": (0, 1)})
    with pytest.raises(ServiceError, match="no condition family 'fog'"):
        conditions_build(["fog"])
    rows = conditions_summary(built)
    assert [r["family"] for r in rows] == ["light", "latency"]
    assert rows[0]["ranges"] == [("Gamma", "0.9 to 1.1")]  # the rest at their defaults
    assert rows[1]["ranges"] == []


def test_a_clone_keeps_the_setting_unless_told(alice) -> None:
    model = create(alice, conditions=LIGHT)
    clone = services.model_clone(model=model, owner=alice, name="copy")
    assert clone.conditions == model.conditions
    clean = services.model_clone(model=model, owner=alice, name="clean-copy", conditions={})
    assert clean.conditions == {}


def test_training_params_yaml_records_it_under_our_own_key(alice) -> None:
    plain = training_params(create(alice))
    assert "RACECRAFT_CONDITIONS" not in plain
    model = create(alice, name="m2", conditions=LIGHT)
    text = training_params(model)
    yaml = pytest.importorskip("yaml")
    parsed = yaml.safe_load(text)  # still valid YAML: DeepRacer's tools read it as ever
    assert parsed["WORLD_NAME"] == "racecraft_oval"
    assert conditions_from_param(parsed["RACECRAFT_CONDITIONS"]) == model.conditions
    flat = read_training_params({"ip/training_params.yaml": text.encode()})
    assert conditions_from_param(flat["RACECRAFT_CONDITIONS"]) == model.conditions
    assert conditions_from_param("not json") == {} == conditions_from_param("")
    assert conditions_from_param('{"families": {"fog": {}}}') == {}


def test_a_curriculum_is_kept_through_training_params_yaml_and_old_lines_load(alice) -> None:
    model = create(alice, conditions={**LIGHT, "ramp_episodes": 60})
    assert model.conditions["ramp_episodes"] == 60
    plain = create(alice, name="m2", conditions=LIGHT).conditions
    assert "ramp_episodes" not in plain and model.conditions["families"] == plain["families"]
    text = training_params(model)
    flat = read_training_params({"ip/training_params.yaml": text.encode()})
    assert conditions_from_param(flat["RACECRAFT_CONDITIONS"]) == model.conditions
    old = '{"families":{"light":{}}}'  # a line written before the curriculum: no field
    assert "ramp_episodes" not in conditions_from_param(old)
    assert conditions_from_param(old)["families"]["light"]["gamma"] == [0.85, 1.2]
    with pytest.raises(ServiceError, match="ramp_episodes must be"):
        create(alice, name="m3", conditions={**LIGHT, "ramp_episodes": -5})


@pytest.mark.slow  # the import runs in a bounded child process
def test_our_archive_imports_with_its_setting(alice, ppo_discrete) -> None:
    model = create(alice, conditions=LIGHT,
                   action_space=ppo_discrete.metadata.actions.to_metadata())  # fmt: skip
    get_store().put_bytes(keys_for(model.pk).best, checkpoint_bytes(ppo_discrete.model))
    RacingModel.objects.filter(pk=model.pk).update(has_checkpoint=True)
    model.refresh_from_db()
    copy = services.model_import(owner=alice, name="back", upload=virtual_model_archive(model))
    assert copy.conditions == model.conditions and copy.conditions
