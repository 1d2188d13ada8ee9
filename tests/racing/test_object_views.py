"""Boxes and bot cars in the camera images and the video: drawn over the ground, nearer over
farther, nothing behind the lens."""

from __future__ import annotations

import numpy as np

from racing.car import Pose
from racing.drawing import BoxSet, box_corners, draw_boxes
from racing.env import RacingEnv
from racing.objects import Lanes
from racing.race import RaceConfig
from racing.sensors import CameraMount, camera_frame, intrinsics

BOX_AT = 0.1  # on the start straight of reinvent_base


def pair(track, sensors=("FRONT_FACING_CAMERA",), **kwargs) -> tuple[RacingEnv, RacingEnv]:
    """The same car with one box in the inner lane, and without it (a time trial)."""
    race = RaceConfig(race_type="OBJECT_AVOIDANCE", object_positions=((BOX_AT, 1),))
    return (
        RacingEnv(track, race=race, sensors=list(sensors), start="start_line", **kwargs),
        RacingEnv(track, sensors=list(sensors), start="start_line", **kwargs),
    )


def reset_both(envs, s: float, offset: float):
    options = {"start_progress": 100 * s / envs[0].track.length, "offset": offset}
    return [env.reset(seed=0, options=options)[0] for env in envs]


def test_the_camera_shows_a_box_ahead(reinvent):
    envs = pair(reinvent, sensors=("STEREO_CAMERAS",))
    box_s = BOX_AT * reinvent.length
    with_box, without = reset_both(envs, box_s - 1.2, offset=Lanes(reinvent).offset(0.0, 1))
    changed = with_box != without
    assert changed.sum() > 300  # a 0.39 m box 1 m ahead covers a good part of the image
    # It stands in the middle of both views, above the bottom rows (the road just ahead).
    rows, cols = np.nonzero(changed[..., 0])
    assert 50 < cols.mean() < 110 and rows.max() < 119
    assert not np.array_equal(changed[..., 0], changed[..., 1])  # two lenses, two views
    assert envs[0].params["object_in_camera"] is True


def test_a_box_behind_the_camera_is_not_drawn(reinvent):
    envs = pair(reinvent)
    with_box, without = reset_both(envs, BOX_AT * reinvent.length + 0.8, offset=0.0)
    assert np.array_equal(with_box, without)
    assert envs[0].params["object_in_camera"] is False  # the next object is ahead, far away


def test_nearer_boxes_cover_farther_ones():
    # The wide 120° lens the scene was laid out for (DeepRacer's own is narrower).
    mount = CameraMount(forward=0.2, height=0.12, pitch_deg=20.0, hfov_deg=120.0)
    pose = Pose(0.0, 0.0, 0.0)
    pos, rot = camera_frame(pose, mount)
    near = box_corners(1.0, 0.0, 0.0, 0.24, 0.39, 0.27)
    far = box_corners(1.6, 0.0, 0.0, 0.24, 0.6, 0.5)  # bigger, so its edges show round the near one
    red, blue = (250, 0, 0), (0, 0, 250)
    for order in ([near, far], [far, near]):
        colours = [red, blue] if order[0] is near else [blue, red]
        img = np.zeros((mount.height_px, mount.width, 3), np.uint8)
        draw_boxes(img, intrinsics(mount), pos, rot, BoxSet.build(np.stack(order), colours))
        centre = img[42, 80]  # the near box's face, above the middle of the view
        assert centre[0] > 100 and centre[2] == 0
        assert (img[..., 2] > 100).sum() > 50  # the far one shows round it
    # Wholly behind the camera: nothing; partly behind: only the part in front, no error.
    img = np.zeros((mount.height_px, mount.width, 3), np.uint8)
    behind = box_corners(-0.5, 0.0, 0.0, 0.24, 0.39, 0.27)
    straddling = box_corners(0.2, 0.35, 0.0, 1.0, 0.39, 0.27)
    draw_boxes(img, intrinsics(mount), pos, rot, BoxSet.build(np.stack([behind]), [red]))
    assert not img.any()
    draw_boxes(img, intrinsics(mount), pos, rot, BoxSet.build(np.stack([straddling]), [red]))
    assert img[..., 0].any()


def test_the_video_shows_boxes_and_bots(reinvent):
    box_rgb = np.array([201, 160, 99])
    for view in ("chase", "top_down"):
        env, _ = pair(reinvent, render_mode="rgb_array", render_view=view)
        reset_both([env], BOX_AT * reinvent.length - 1.2, offset=0.0)
        frame = env.render().astype(int)
        # The lit top face of the box, in its own colour.
        assert (np.abs(frame - box_rgb).sum(axis=2) < 30).sum() > 10, view
    race = RaceConfig(race_type="HEAD_TO_BOT", number_of_bots=2)
    bots = RacingEnv(reinvent, race=race, render_mode="rgb_array", render_view="top_down")
    bots.reset(seed=0)
    frame = bots.render().astype(int)
    assert (np.abs(frame - np.array([60, 110, 220])).sum(axis=2) < 30).sum() > 4


def test_a_time_trial_never_touches_the_object_machinery(reinvent, monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("object code ran in a time trial")

    monkeypatch.setattr("racing.sensors.draw_boxes", refuse)
    monkeypatch.setattr("racing.world.RaceWorld.crash", refuse)
    monkeypatch.setattr("racing.world.RaceWorld.advance", refuse)
    monkeypatch.setattr("racing.world.RaceWorld.reset", refuse)
    env = RacingEnv(reinvent, sensors=["STEREO_CAMERAS"])
    obs, _ = env.reset(seed=0)
    for _ in range(30):
        obs, *_ = env.step(5)
    assert isinstance(obs, np.ndarray) and obs.shape == (120, 160, 2)
    assert env.objects == ()


def test_the_camera_shows_a_bot_ahead_and_not_one_behind(reinvent):
    race = RaceConfig(race_type="HEAD_TO_BOT", number_of_bots=1)  # 2 m along, inner lane
    envs = (
        RacingEnv(reinvent, race=race, start="start_line"),
        RacingEnv(reinvent, start="start_line"),
    )
    with_bot, without = reset_both(envs, 0.8, offset=Lanes(reinvent).offset(0.8, 1))
    assert (with_bot != without).sum() > 100
    with_bot, without = reset_both(envs, 3.4, offset=0.0)  # past the bot, which is behind
    assert np.array_equal(with_bot, without)
