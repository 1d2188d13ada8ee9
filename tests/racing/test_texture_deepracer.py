"""The ground the camera sees has DeepRacer's grayscale look: its asphalt, borders, centre line
and grass, compared with real DeepRacer camera frames (deepracer-utils' sample pictures)."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from racing.car import Pose
from racing.sensors import CameraMount, PinholeCamera, camera_frame, ground_for, intrinsics
from racing.texture import BORDER_RGB, CENTRE_DASH_M, CENTRE_RGB, FLOOR_RGB, ROAD_RGB
from racing.tracks import TrackCatalog
from tests.training.interchange.deepracer_support import CACHE, aws_samples

CLASSES = {"road": ROAD_RGB, "border": BORDER_RGB, "centre": CENTRE_RGB, "grass": FLOOR_RGB}


def gray(rgb: tuple[int, int, int]) -> float:
    return 0.299 * rgb[0] + 0.587 * rgb[1] + 0.114 * rgb[2]


def deepracer_class_means() -> dict[str, float]:
    """Mean grayscale of each surface on DeepRacer's frames, segmented by hue."""
    aws_samples()  # downloads the pictures once (or skips)
    sums = {name: [] for name in CLASSES}
    for picture in sorted((CACHE / "pictures").glob("*.png")):
        bgr = cv2.imread(str(picture))
        h, s, v = (c.astype(int) for c in cv2.split(cv2.cvtColor(bgr, cv2.COLOR_BGR2HSV)))
        y = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY).astype(float)
        masks = {
            "road": (h >= 95) & (h <= 130) & (s > 40) & (v >= 40) & (v < 140),
            "border": (s < 40) & (v > 170),
            "centre": (h >= 8) & (h <= 25) & (s > 150) & (v > 150),
            "grass": (h >= 45) & (h <= 85) & (s > 40) & (v > 80),
        }
        for name, mask in masks.items():
            sums[name].append(y[mask])
    return {name: float(np.concatenate(parts).mean()) for name, parts in sums.items()}


@pytest.mark.slow
def test_surfaces_have_deepracers_gray_levels() -> None:
    measured = deepracer_class_means()
    for name, rgb in CLASSES.items():
        assert abs(gray(rgb) - measured[name]) < 6, (name, gray(rgb), measured[name])


def test_camera_frame_shows_the_surfaces_in_order() -> None:
    """Ahead on a straight of a DeepRacer-wide track: asphalt in the middle, the centre line,
    white borders, grass beyond them."""
    track = TrackCatalog().load("racecraft_summit")  # 0.76 m wide, as DeepRacer's tracks
    camera = PinholeCamera(ground_for(track, resolution=0.005, rgb=False))
    s = 5.0
    x, y = track.point_at(s)
    frame = camera.render(Pose(x, y, track.heading_at(s)))
    row = frame[-20].astype(int)
    assert abs(np.median(row[40:120]) - gray(ROAD_RGB)) < 4  # asphalt ahead
    assert gray(ROAD_RGB) + 40 < row[70:90].max() <= gray(CENTRE_RGB) + 2  # the centre line
    assert frame.max() >= gray(BORDER_RGB) - 6  # a border in view
    ground = frame[camera.first_ground_row + 2 :].astype(int)
    assert (np.abs(ground - gray(FLOOR_RGB)) < 4).mean() > 0.05  # grass beyond the borders


def deepracer_frames() -> list[np.ndarray]:
    """DeepRacer's camera frames as the agent sees them: 160×120 grayscale."""
    aws_samples()  # downloads the pictures once (or skips)
    frames = []
    for picture in sorted((CACHE / "pictures").glob("*.png")):
        small = cv2.resize(cv2.imread(str(picture)), (160, 120), interpolation=cv2.INTER_AREA)
        frames.append(cv2.cvtColor(small, cv2.COLOR_BGR2GRAY))
    return frames


def ground_top(frame: np.ndarray) -> int:
    """The row below the lowest dark row of the frame's upper half (the walls' foot): where
    the ground (the far grass) begins, just below the horizon."""
    dark = np.flatnonzero(np.median(frame[:60].astype(int), axis=1) < 30)
    return int(dark.max()) + 1 if dark.size else 0


def ahead_on(track, progress: float) -> Pose:
    s = progress / 100 * track.length
    x, y = track.point_at(s)
    return Pose(x, y, track.heading_at(s))


def test_horizon_and_walls_are_where_deepracers_are(reinvent) -> None:
    """DeepRacer's frames: dark walls (median ~2-25) down to ~28% of the frame, then the grass
    and the track; asphalt fills the bottom rows. Our camera at DeepRacer's mount and lens
    (SimApp's racecar) shows the same rows, walls as dark and the same asphalt below."""
    theirs = deepracer_frames()
    camera = PinholeCamera(ground_for(reinvent, resolution=0.005, rgb=False))
    ours = [camera.render(ahead_on(reinvent, p)) for p in (0, 15, 30, 45, 60, 75, 90)]
    their_rows = [ground_top(f) for f in theirs]
    our_rows = [ground_top(f) for f in ours]
    assert min(their_rows) >= 28 and max(their_rows) <= 40, their_rows  # ~24-31% of 120
    assert min(their_rows) - 2 <= np.median(our_rows) <= max(their_rows) + 2, (
        our_rows,
        their_rows,
    )
    for frames, rows in ((theirs, their_rows), (ours, our_rows)):
        for frame, row in zip(frames, rows, strict=True):
            assert np.median(frame[: row - 1]) < 30, row  # walls (ours: the backdrop) are dark
    # The bottom rows: mostly asphalt (the car sees the road ahead, not its borders).
    their_road = np.median([np.median(f[-20:]) for f in theirs])
    our_road = np.median([np.median(f[-20:]) for f in ours])
    assert abs(their_road - our_road) < 6, (their_road, our_road)
    asphalt = [((f[-20:] > 35) & (f[-20:] < 75)).mean() for f in ours]
    assert np.median(asphalt) > 0.8, asphalt


def test_deepracers_dashes_are_evenly_spaced_through_our_lens() -> None:
    """The centre-line dashes on DeepRacer's frames (640×480), projected back to the ground
    through our camera's mount and lens, are evenly spaced and as far apart as ours: the
    right pitch, height and field of view (a wrong pitch stretches or squeezes the far ones)."""
    aws_samples()
    mount = replace(CameraMount(), width=640, height_px=480)
    pos, rot = camera_frame(Pose(0.0, 0.0, 0.0), mount)
    to_ray = rot.T @ np.linalg.inv(intrinsics(mount))
    gaps = []
    for picture in sorted((CACHE / "pictures").glob("*.png")):
        hsv = cv2.cvtColor(cv2.imread(str(picture)), cv2.COLOR_BGR2HSV).astype(int)
        orange = (hsv[..., 0] >= 8) & (hsv[..., 0] <= 25) & (hsv[..., 1] > 150)
        n, _, stats, centres = cv2.connectedComponentsWithStats(
            (orange & (hsv[..., 2] > 150)).astype(np.uint8)
        )
        # Whole dashes: not specks, not cut by the bottom edge.
        whole = [i for i in range(1, n) if stats[i, 4] >= 30 and stats[i, 1] + stats[i, 3] < 479]
        rays = to_ray @ np.column_stack([centres[whole], np.ones(len(whole))]).T
        ground = (pos[:, None] + rays * (-pos[2] / rays[2]))[:2].T
        ground = ground[np.argsort(ground[:, 0])]
        gaps += list(np.linalg.norm(np.diff(ground, axis=0), axis=1))
    gaps = np.array(gaps)
    assert len(gaps) >= 20
    assert gaps.std() / gaps.mean() < 0.05, gaps.round(3)
    assert abs(gaps.mean() - 2 * CENTRE_DASH_M) < 0.1 * 2 * CENTRE_DASH_M, gaps.mean()
