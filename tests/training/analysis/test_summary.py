"""A run's summary (Django-free): iterations folded in once, in any order, the stored form read
back without unpickling, and action bins for continuous action spaces."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest

from racing.tracks import TrackCatalog
from training.analysis import charts
from training.analysis.actions import SPEED_BINS, STEERING_BINS, ActionBins
from training.analysis.summary import RunSummary, SummaryError
from training.analysis.synthetic import synthetic_iteration
from training.analysis.trace import Grid, parse_simtrace, summarize

TRACK = TrackCatalog([]).load("racecraft_oval")
GRID = Grid.around(TRACK.bounds())
DISCRETE = ActionBins.for_action_space(
    [{"steering_angle": a, "speed": v} for a in (-30, 0, 30) for v in (1, 2)]
)
CONTINUOUS_SPACE = {
    "steering_angle": {"low": -20.0, "high": 30.0},
    "speed": {"low": 1.0, "high": 2.5},
}
CONTINUOUS = ActionBins.for_action_space(CONTINUOUS_SPACE)


def _part(iteration: int, bins: ActionBins = DISCRETE, **kwargs):
    continuous = ((-20.0, 30.0), (1.0, 2.5)) if bins.continuous else None
    data = synthetic_iteration(TRACK, iteration=iteration, episodes=6, num_actions=len(bins),
                               mean_steps=30, continuous=continuous, **kwargs)  # fmt: skip
    return summarize(parse_simtrace(data), iteration=iteration, grid=GRID, bins=bins,
                     num_waypoints=TRACK.num_waypoints)  # fmt: skip


def _empty(bins: ActionBins = DISCRETE) -> RunSummary:
    return RunSummary.empty(GRID, bins, TRACK.num_waypoints)


def _chart_data(run: RunSummary) -> list:
    """Every chart's data; heatmap means to 2 digits (sums taken in another order may differ
    in the last bit, and so round the other way at 3)."""
    heatmaps = [charts.heatmap(run, k) for k in charts.HEATMAPS]
    for heat in heatmaps:
        heat["values"] = [None if v is None else round(v, 2) for v in heat["values"]]
    return [charts.progress(run, {}), charts.episodes_table(run), charts.fastest_laps(run),
            charts.action_usage(run), *heatmaps]  # fmt: skip


def test_iterations_fold_in_once_in_any_order() -> None:
    parts = [_part(i) for i in range(4)]
    at_once = _empty().merged(parts)
    one_by_one = _empty()
    for part in (parts[2], parts[0], parts[3], parts[1], parts[2]):  # out of order, one twice
        one_by_one = one_by_one.merged([part])
    assert one_by_one.iterations.tolist() == [0, 1, 2, 3] == sorted(at_once.covered)
    assert one_by_one.num_steps == sum(p.num_steps for p in parts) == at_once.num_steps
    assert _chart_data(one_by_one) == _chart_data(at_once)
    assert one_by_one.merged(parts) is one_by_one  # nothing new: the same object
    assert _empty().merged([parts[1], parts[1]]).num_steps == parts[1].num_steps
    table = charts.episodes_table(one_by_one)
    assert table["episode"] == list(range(24)) and table["iteration"] == sorted(table["iteration"])
    assert charts.progress(one_by_one, {})["episodes"] == [6, 6, 6, 6]


def test_the_stored_form_round_trips_and_refuses_what_it_cannot_trust() -> None:
    run = _empty().merged([_part(0), _part(1)])
    data = run.to_bytes()
    back = RunSummary.from_bytes(data, DISCRETE)
    assert back.fits(GRID, DISCRETE, TRACK.num_waypoints)
    assert back.covered == {0, 1} and _chart_data(back) == _chart_data(run)
    with pytest.raises(SummaryError, match="other actions"):
        RunSummary.from_bytes(data, CONTINUOUS)
    for bad in (b"", b"not a zip", data[: len(data) // 2]):
        with pytest.raises(SummaryError):
            RunSummary.from_bytes(bad, DISCRETE)
    # An object array (a pickle) is never loaded, whatever the header says.
    with np.load(io.BytesIO(data)) as npz:
        arrays = {name: npz[name] for name in npz.files}
    evil = io.BytesIO()
    np.savez(evil, **{**arrays, "grid_count": np.array([object()], dtype=object)})
    with pytest.raises(SummaryError):
        RunSummary.from_bytes(evil.getvalue(), DISCRETE)
    # Arrays that do not fit together are refused, not charted.
    short = io.BytesIO()
    np.savez(short, **{**arrays, "grid_count": arrays["grid_count"][:10]})
    with pytest.raises(SummaryError, match="do not fit"):
        RunSummary.from_bytes(short.getvalue(), DISCRETE)
    old = io.BytesIO()
    header = {**json.loads(arrays["header"].tobytes()), "version": 0}
    np.savez(old, **{**arrays, "header": np.frombuffer(json.dumps(header).encode(), np.uint8)})
    with pytest.raises(SummaryError, match="version"):
        RunSummary.from_bytes(old.getvalue(), DISCRETE)


def test_a_summary_made_another_way_does_not_fit() -> None:
    run = _empty()
    assert not run.fits(Grid.around(TRACK.bounds(), cells=60), DISCRETE, TRACK.num_waypoints)
    assert not run.fits(GRID, CONTINUOUS, TRACK.num_waypoints)
    assert not run.fits(GRID, DISCRETE, TRACK.num_waypoints + 1)


def test_continuous_actions_are_binned_on_a_steering_by_speed_grid() -> None:
    assert len(CONTINUOUS) == STEERING_BINS * SPEED_BINS and CONTINUOUS.continuous
    assert CONTINUOUS.names[0] == "-20..-10° 1.00..1.50 m/s"
    assert CONTINUOUS.names[-1] == "20..30° 2.00..2.50 m/s"
    steer = np.array([-20.0, -19.0, 0.0, 29.9, 30.0, 45.0, -90.0])
    speed = np.array([1.0, 2.4, 1.6, 1.0, 2.5, 4.0, 0.1])
    index = CONTINUOUS.index(np.full(len(steer), -1.0), steer, speed)
    # steering bins of 10° from -20, speed bins of 0.5 m/s from 1; outside: the border bins
    assert index.tolist() == [0, 2, 2 * 3 + 1, 4 * 3, 4 * 3 + 2, 4 * 3 + 2, 0]

    run = _empty(CONTINUOUS).merged([_part(0, CONTINUOUS), _part(1, CONTINUOUS)])
    usage = charts.action_usage(run)
    assert len(usage["per_iteration"]) == 2
    for row in usage["per_iteration"] + usage["per_section"]:
        assert len(row) == 15 and abs(sum(row) - 100) < 0.1
    # uniform steering and speed: every bin is used, none takes much more than its share
    assert all(2 < share < 12 for share in usage["per_iteration"][0])
    heat = charts.heatmap(run, "action")
    seen = {v for v in heat["values"] if v is not None}
    assert len(seen) > 5 and seen <= set(range(15))
    assert int(run.grid_actions.sum()) == run.num_steps  # every step has its bin


def test_discrete_bins_count_the_logged_index() -> None:
    assert DISCRETE.names == ("-30° 1 m/s", "-30° 2 m/s", "0° 1 m/s", "0° 2 m/s", "30° 1 m/s",
                              "30° 2 m/s")  # fmt: skip
    index = DISCRETE.index(np.array([0.0, 5.0, 6.0, -1.0]), np.zeros(4), np.zeros(4))
    assert index.tolist() == [0, 5, -1, -1]  # outside the space: no bin
    unreadable = ActionBins.for_action_space({"steering_angle": "wide"})
    assert len(unreadable) == 0
    run = _empty(unreadable).merged([_part(0, unreadable)])
    assert charts.action_usage(run)["per_iteration"] == [[]]
    assert all(v is None for v in charts.heatmap(run, "action")["values"])
    assert charts.heatmap(run, "speed")["steps"] == run.num_steps > 0
