"""What the example rewards pay, on hand-made params: the racing preset's speed along the
track, and the same easing off before bends."""

from __future__ import annotations

import pytest

from training.rewards.examples import example_source


def reward_of(example_id: str):
    namespace: dict = {}
    exec(compile(example_source(example_id), example_id, "exec"), namespace)  # trusted: ours
    return namespace["reward_function"]


def corner_track() -> list[tuple[float, float]]:
    """3 m straight along x every 0.25 m, then 3 m up y: a 90° bend at (3, 0)."""
    along = [(0.25 * i, 0.0) for i in range(13)]
    up = [(3.0, 0.25 * i) for i in range(1, 13)]
    return along + up


def params(at: int, speed: float, heading: float = 0.0) -> dict:
    return {"waypoints": corner_track(), "closest_waypoints": [at, at + 1], "heading": heading,
            "speed": speed, "is_offtrack": False, "all_wheels_on_track": True}  # fmt: skip


@pytest.mark.parametrize("speed", [2.0, 3.0, 3.5])
def test_far_from_a_bend_it_pays_what_the_racing_preset_s_reward_pays(speed) -> None:
    plain, bends = reward_of("speed_along_track"), reward_of("speed_along_track_bends")
    assert bends(params(1, speed)) == plain(params(1, speed)) == pytest.approx(speed**2 / 4)


def test_into_a_bend_it_pays_half_for_a_speed_above_3_m_s_and_all_below() -> None:
    plain, bends = reward_of("speed_along_track"), reward_of("speed_along_track_bends")
    near = 8  # 2.0 m along: the bend 1.0 m ahead
    assert bends(params(near, 3.5)) == pytest.approx(plain(params(near, 3.5)) / 2)
    assert bends(params(near, 3.0)) == plain(params(near, 3.0))
    # The direction of the track there, not the car's, says what a bend is.
    assert bends(params(near, 3.5, heading=10.0)) == pytest.approx(
        plain(params(near, 3.5, heading=10.0)) / 2
    )


def test_off_the_track_it_pays_almost_nothing() -> None:
    bends = reward_of("speed_along_track_bends")
    assert bends({**params(8, 3.5), "all_wheels_on_track": False}) == 1e-3
    assert bends({**params(8, 3.5), "is_offtrack": True}) == 1e-3
