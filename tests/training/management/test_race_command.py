"""``manage.py racecraft_race``: stored models raced head to head through the database and the
store; the JSON contract, a crash between racers, determinism, the broadcast MP4, sim-traces
that deepracer-utils reads, and cars that cannot race. (Alice and Bob race; Carol's model was
never trained.)"""

from __future__ import annotations

import io
import json

import av
import pytest
from django.core.management import call_command
from django.core.management.base import CommandError

from tests.support import constant
from training.store import get_store, keys_for

CONTRACT = {"model", "name", "position", "finished", "lap_times_s", "total_time_s", "progress",
            "off_track", "crashes", "resets"}  # fmt: skip


def race(*args: object) -> dict:
    out = io.StringIO()
    call_command("racecraft_race", *map(str, args), "--json", stdout=out)
    return json.loads(out.getvalue())


def test_two_models_race_and_the_one_behind_crashes_into_the_other(racer_model, tmp_path):
    # Alice's car (pole) turns across the outer lane; Bob's comes fast behind it.
    alice = racer_model("alice", constant(-30, 0.5))
    bob = racer_model("bob", constant(5, 1.5), sensors=["FRONT_FACING_CAMERA", "SECTOR_LIDAR"])
    video = tmp_path / "race.mp4"
    args = (alice.pk, bob.pk, "--track", "racecraft_oval", "--laps", "1", "--time-limit", "10")
    result = race(*args, "--video", video, "--traces", tmp_path / "traces")
    cars = {car["model"]: car for car in result["cars"]}
    assert set(cars) == {alice.pk, bob.pk}
    assert all(set(car) >= CONTRACT for car in cars.values())
    assert cars[bob.pk]["crashes"] >= 1
    assert cars[bob.pk]["resets"] >= cars[bob.pk]["crashes"]
    assert sorted(car["position"] for car in cars.values()) == [1, 2]
    assert result["winner"] == result["cars"][0]["model"]
    assert (result["track"], result["laps"], result["steps"]) == ("racecraft_oval", 1, 150)
    assert race(*args) == result  # the same race twice: the same JSON

    with av.open(str(video)) as container:
        stream = container.streams.video[0]
        assert (stream.width, stream.height) == (1280, 720)
        assert sum(1 for _ in container.decode(stream)) == 150
    logs = pytest.importorskip("deepracer.logs")
    first_crash = {}
    for model in (alice, bob):
        log = logs.DeepRacerLog(model_folder=str(tmp_path / "traces" / str(model.pk)))
        log.load_evaluation_trace(force=True)
        df = log.dataframe()
        assert df["episode"].nunique() >= 1
        agg = logs.AnalysisUtils.simulation_agg(df, firstgroup="stream", is_eval=True)
        assert (agg["steps"] > 0).all()
        crashed = df[df["episode_status"] == "crashed"]["tstamp"]
        first_crash[model.pk] = crashed.min() if len(crashed) else float("inf")
    # Bob ran into Alice from behind: the first crash is his, and Alice's lap went on.
    assert first_crash[bob.pk] < first_crash[alice.pk]


def test_a_model_that_cannot_race_is_out_with_the_reason_and_the_race_goes_on(
    racer_model, store_dir
):
    alice = racer_model("alice", constant(0, 1.0))
    carol = racer_model("carol", constant(0, 1.0), trained=False)
    bob = racer_model("bob", constant(0, 1.0))
    get_store().put_bytes(keys_for(bob.pk).best, b"not a checkpoint")
    dave = racer_model("dave", constant(0, 1.0))
    (store_dir / keys_for(dave.pk).best).unlink()  # its file went missing from the store
    result = race(alice.pk, carol.pk, bob.pk, dave.pk, "--track", "racecraft_oval",
                  "--laps", "1", "--time-limit", "10")  # fmt: skip
    cars = {car["model"]: car for car in result["cars"]}
    assert cars[carol.pk]["reason"] == "it has no trained checkpoint"
    assert cars[bob.pk]["reason"].startswith("its checkpoint cannot be loaded")
    assert cars[dave.pk]["reason"].startswith("its checkpoint cannot be loaded")
    assert all(cars[m.pk]["status"] == "out" and cars[m.pk]["position"] > 1
               for m in (carol, bob, dave))  # fmt: skip
    assert cars[alice.pk]["position"] == 1 and result["winner"] == alice.pk


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("{a}",), "a race has 2 to 4 models, not 1"),
        (("{a}", "{a}"), "only one place on the grid"),
        (("{a}", "999999"), "no model with id 999999"),
        (("{a}", "{b}", "--laps", "0"), "1 to 10 laps"),
        (("{a}", "{b}", "--bots", "7"), "number_of_bots must be an integer from 1 to 6"),
        (("{a}", "{b}", "--bots", "6", "--bot-speed", "9"), "bot_speed must be"),
    ],
)
def test_bad_input_is_a_clear_error(racer_model, args, message):
    a, b = racer_model("alice", constant(0, 1.0)), racer_model("bob", constant(0, 1.0))
    filled = [arg.format(a=a.pk, b=b.pk) for arg in args]
    with pytest.raises(CommandError, match=message):
        call_command("racecraft_race", *filled, "--track", "racecraft_oval", "--json",
                     stdout=io.StringIO())  # fmt: skip
