"""Where a model lives in the store: ``u<owner>-<name>/`` for new models (DeepRacer tools read
a model under its own name), the id folder for models stored before that."""

from __future__ import annotations

import pytest
from django.contrib.auth import get_user_model

from training import services
from training.models import RacingModel
from training.store import get_store, keys_for

pytestmark = pytest.mark.django_db
REWARD = "def reward_function(params):\n    return 1.0\n"


@pytest.fixture
def owner(settings, tmp_path):
    settings.STORE_DIR = tmp_path / "store"
    return get_user_model().objects.create_user("olive", password="pw-olive-123")


def _model(owner, name: str) -> RacingModel:
    return services.model_create(owner=owner, name=name, track_id="racecraft_oval",
                                 action_space=[{"steering_angle": 0, "speed": 1}] * 2,
                                 reward_function=REWARD, validate_reward=False)  # fmt: skip


def test_new_models_live_under_their_owner_and_name(owner) -> None:
    model = _model(owner, "my-model")
    assert model.store_prefix == f"u{owner.pk}-my-model"
    keys = keys_for(model.pk)
    assert keys.prefix == f"u{owner.pk}-my-model/"
    assert get_store().exists(keys.metadata) and get_store().exists(keys.reward_function)


def test_older_models_keep_their_id_folder(owner) -> None:
    model = _model(owner, "old-one")
    RacingModel.objects.filter(pk=model.pk).update(store_prefix="")
    assert keys_for(model.pk).prefix == f"{model.pk}/"


def test_deleting_a_model_empties_its_folder(owner) -> None:
    model = _model(owner, "short-lived")
    prefix = keys_for(model.pk).prefix
    services.model_delete(model=model, user=owner)
    assert get_store().list(prefix) == []
