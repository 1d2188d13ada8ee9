"""A small model for the service tests, created through the service (no reward run)."""

from __future__ import annotations

from training import services
from training.models import RacingModel

ACTIONS = [{"steering_angle": a, "speed": 1.0} for a in (-30, 0, 30)]
REWARD = "def reward_function(params):\n    return 1.0\n"


def create(owner, **overrides) -> RacingModel:
    kwargs = dict(owner=owner, name="m1", track_id="racecraft_oval", action_space=ACTIONS,
                  reward_function=REWARD, validate_reward=False)  # fmt: skip
    kwargs.update(overrides)
    return services.model_create(**kwargs)
