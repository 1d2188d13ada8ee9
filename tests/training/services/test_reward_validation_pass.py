"""The worker's side of saving after a validation: a validation that passes is remembered for
its user, source, track and direction (and for an hour only); one that fails is not."""

from __future__ import annotations

import pytest
from django.conf import settings

from training.services import rewards

GOOD = "def reward_function(params):\n    return 1.0\n"
BAD = "def reward_function(params):\n    return params['nope']\n"


def passed(user_id: int, source: str) -> bool:
    return rewards.reward_validation_passed(
        user_id=user_id, source=source, track_id="racecraft_oval", direction="native"
    )


@pytest.mark.slow
def test_a_pass_is_remembered_for_its_user_only() -> None:
    result = rewards.reward_validation_run(
        source=GOOD, track_id="racecraft_oval", direction="native", user_id=4101
    )
    assert result["ok"] is True
    assert passed(4101, GOOD) and passed(4101, GOOD.replace("\n", "\r\n"))
    assert not passed(4102, GOOD)
    failed = rewards.reward_validation_run(
        source=BAD, track_id="racecraft_oval", direction="native", user_id=4101
    )
    assert failed["ok"] is False and not passed(4101, BAD)
    import redis

    client = redis.Redis.from_url(settings.REDIS_URL)
    try:
        ttl = client.ttl(rewards._pass_key(4101, GOOD, "racecraft_oval", "native"))
    finally:
        client.close()
    assert 0 < ttl <= rewards.PASS_TTL_S
