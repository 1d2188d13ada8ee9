"""The run's summary in the store: the training job's iteration hook folds each logged iteration
in (real JobHooks, real cars, the store on disk), and the charts then read that one object,
never the sim-traces; a summary that cannot be trusted is rebuilt from the files."""

from __future__ import annotations

import uuid
from concurrent.futures import ThreadPoolExecutor

import pytest
from django.contrib.auth import get_user_model
from django.db import connections

from tests.support import S3_ACCESS_KEY, S3_SECRET_KEY
from training import services
from training.analysis.actions import ActionBins
from training.analysis.summary import RunSummary
from training.analysis.synthetic import synthetic_iteration
from training.analysis.trace import parse_simtrace
from training.models import JobStatus, RacingModel, TrainingJob
from training.rl.runner import EvaluationOutcome, IterationResult
from training.rollout.envs import EnvSpec, EpisodeBook
from training.services import analysis
from training.storage import StoreError
from training.store import get_store, keys_for
from training.worker import training as worker_training

pytestmark = [pytest.mark.django_db, pytest.mark.usefixtures("store_dir")]
ACTIONS = [{"steering_angle": a, "speed": 2.0} for a in (-30, 0, 30)]
REWARD = "def reward_function(params):\n    return 1.0\n"
PER_ITERATION = 3


@pytest.fixture(autouse=True)
def _fresh_process_cache():
    analysis.analysis_cache_clear()
    yield
    analysis.analysis_cache_clear()


def _model(name: str = "m1", action_space=None) -> RacingModel:
    owner = get_user_model().objects.create_user(f"owner-{name}", password="pw-owner-123")
    return services.model_create(
        owner=owner, name=name, track_id="racecraft_oval",
        action_space=action_space or ACTIONS, validate_reward=False, reward_function=REWARD,
        hyperparameters={"num_episodes_between_training": PER_ITERATION},
    )  # fmt: skip


def _drive(model: RacingModel, hooks: worker_training.JobHooks, episodes: int) -> list[list]:
    """``episodes`` episodes of one car, reported to the hooks as a rollout reports them;
    returns the rows for the iteration hook."""
    env = EnvSpec(track="racecraft_oval", action_space=model.action_space).make(
        reward_function=lambda params: 1.0 - params["distance_from_center"]
    )
    book, rows = EpisodeBook(env), []
    for n in range(episodes):
        env.reset(seed=3 if n == 0 else None)
        book.reset()
        for step in range(400):
            _, reward, terminated, truncated, info = env.step(step % len(model.action_space))
            done = terminated or truncated
            rows.append(book.trace(info["trace"], done))
            entry = book.step(reward, info, done)
            if entry is not None:
                hooks.on_episode(entry)
                break
    env.close()
    return rows


def _result(iteration: int) -> IterationResult:
    return IterationResult(
        iteration=iteration, episodes=PER_ITERATION, steps=0, total_steps=0, train_reward=0.0,
        train_progress=0.0, evaluation=EvaluationOutcome([10.0], ["off_track"], [[]], [1.0]),
        elapsed_s=1.0, rollout_s=1.0, update_s=0.0, eval_s=0.0,
    )  # fmt: skip


def test_the_iteration_hook_keeps_the_summary_and_the_charts_read_only_it(monkeypatch):
    model = _model()
    job = TrainingJob.objects.create(model=model, max_minutes=5, status=JobStatus.IN_PROGRESS)
    hooks = worker_training.JobHooks(job)
    store, keys = get_store(), keys_for(model.pk)
    try:
        for iteration in (1, 2):
            rows = _drive(model, hooks, PER_ITERATION)
            hooks.on_iteration(_result(iteration), b"checkpoint", rows)
            stored = RunSummary.from_bytes(store.get_bytes(keys.prefix + analysis.SUMMARY_NAME),
                                           ActionBins.for_action_space(ACTIONS))  # fmt: skip
            assert stored.covered == set(range(iteration))  # the file just logged, folded in
    finally:
        hooks.close()
    files = [parse_simtrace(store.get_bytes(keys.simtrace(it))) for it in (0, 1)]

    def no_parsing(data: bytes):
        raise AssertionError("a chart parsed a sim-trace")

    analysis.analysis_cache_clear()  # a fresh web process: only the store knows the summary
    monkeypatch.setattr(analysis, "parse_simtrace", no_parsing)
    progress = analysis.analysis_chart(model, "progress")
    assert progress["iteration"] == [0, 1] and progress["episodes"] == [3, 3]
    assert progress["eval_progress"] == [10.0, 10.0]
    episodes = analysis.analysis_chart(model, "episodes")
    lengths = [int((f["episode"] == e).sum()) for f in files for e in sorted(set(f["episode"]))]
    assert episodes["steps"] == lengths
    heat = analysis.analysis_chart(model, "heatmap", kind="action")
    assert heat["steps"] == sum(len(f) for f in files) and heat["actions"] == [
        "-30° 2 m/s", "0° 2 m/s", "30° 2 m/s"]  # fmt: skip
    usage = analysis.analysis_chart(model, "actions")
    assert usage["iterations"] == [0, 1] and not usage["continuous"]
    for f, row in zip(files, usage["per_iteration"], strict=True):
        counts = [int((f["action"] == a).sum()) for a in range(3)]
        assert row == pytest.approx([100 * c / len(f) for c in counts], abs=0.01)


def test_a_model_without_a_summary_gets_one_and_new_iterations_are_folded_in(
    monkeypatch, store_dir
):
    model = _model("imported")
    store, keys = get_store(), keys_for(model.pk)
    track = analysis._track(model)
    for it in range(3):
        store.put_bytes(keys.simtrace(it), synthetic_iteration(
            track, iteration=it, episodes=5, num_actions=3, mean_steps=30), "text/csv")  # fmt: skip
    summary_key = keys.prefix + analysis.SUMMARY_NAME
    assert not store.exists(summary_key)
    assert analysis.analysis_chart(model, "progress")["iteration"] == [0, 1, 2]
    assert store.exists(summary_key)  # made from the files once, and saved

    parsed: list[int] = []
    real_parse = analysis.parse_simtrace

    def counting_parse(data: bytes):
        parsed.append(len(data))
        return real_parse(data)

    monkeypatch.setattr(analysis, "parse_simtrace", counting_parse)
    analysis.analysis_cache_clear()
    store.put_bytes(keys.simtrace(3), synthetic_iteration(
        track, iteration=3, episodes=5, num_actions=3, mean_steps=30), "text/csv")  # fmt: skip
    assert analysis.analysis_chart(model, "progress")["iteration"] == [0, 1, 2, 3]
    assert len(parsed) == 1  # only the new file
    assert analysis.analysis_chart(model, "fastest") is not None and len(parsed) == 1

    # A process that kept a summary from long ago takes the store's, which the worker kept
    # up to date, rather than parsing what was logged since.
    old = analysis.analysis_summary(model)
    for it in (4, 5):
        store.put_bytes(keys.simtrace(it), synthetic_iteration(
            track, iteration=it, episodes=5, num_actions=3, mean_steps=30), "text/csv")  # fmt: skip
    analysis.analysis_summary_update(model=model)  # the worker
    assert len(parsed) == 3
    analysis.analysis_cache_clear()
    analysis._lru_put(analysis._summaries, analysis._identity(model), old, 1)
    assert analysis.analysis_chart(model, "progress")["iteration"] == [0, 1, 2, 3, 4, 5]
    assert len(parsed) == 3

    # A damaged summary, or one covering a file that is gone, is rebuilt from the files.
    store.put_bytes(summary_key, b"garbage")
    analysis.analysis_cache_clear()
    assert analysis.analysis_chart(model, "progress")["episodes"] == [5] * 6
    (store_dir / keys.simtrace(5)).unlink()
    assert analysis.analysis_chart(model, "progress")["iteration"] == [0, 1, 2, 3, 4]


def test_the_hook_never_fails_the_training(monkeypatch, caplog):
    model = _model("flaky")
    store, keys = get_store(), keys_for(model.pk)
    store.put_bytes(keys.simtrace(0), b"episode,steps\nnot a trace\n", "text/csv")
    caplog.set_level("WARNING", logger=analysis.__name__)
    analysis.analysis_summary_update(model=model)  # a bad file: logged, not raised
    assert not store.exists(keys.prefix + analysis.SUMMARY_NAME)

    def unavailable(*args, **kwargs):
        raise StoreError("the store is unreachable")

    monkeypatch.setattr(type(store), "list", unavailable)
    analysis.analysis_summary_update(model=model)

    def broken(*args, **kwargs):
        raise IndexError("a bug in the analysis")

    monkeypatch.setattr(analysis, "_up_to_date", broken)
    analysis.analysis_summary_update(model=model)  # logged with its traceback, not raised
    messages = [r.getMessage() for r in caplog.records]
    assert len(messages) == 3 and all("not updated" in m for m in messages)
    assert "not a sim-trace" in messages[0] and "unreachable" in messages[1]
    assert caplog.records[2].exc_info is not None


def test_continuous_models_have_action_charts(monkeypatch):
    space = {"steering_angle": {"low": -30.0, "high": 30.0}, "speed": {"low": 1.0, "high": 3.0}}
    model = _model("continuous", action_space=space)
    store, keys = get_store(), keys_for(model.pk)
    track = analysis._track(model)
    for it in range(2):
        store.put_bytes(keys.simtrace(it), synthetic_iteration(
            track, iteration=it, episodes=6, num_actions=0, mean_steps=40,
            continuous=((-30.0, 30.0), (1.0, 3.0))), "text/csv")  # fmt: skip
    assert "[" in store.get_bytes(keys.simtrace(0)).decode().splitlines()[1].split(",")[7]
    heat = analysis.analysis_chart(model, "heatmap", kind="action")
    assert len(heat["actions"]) == 15 and heat["actions"][0] == "-30..-18° 1.00..1.67 m/s"
    assert {v for v in heat["values"] if v is not None} > {0, 14}
    usage = analysis.analysis_chart(model, "actions")
    assert usage["continuous"] and len(usage["per_iteration"]) == 2
    assert all(len(row) == 15 and abs(sum(row) - 100) < 0.1 for row in usage["per_section"])
    csv = analysis.analysis_csv(model, "actions").splitlines()
    assert csv[0].split(",")[:2] == ["iteration", "-30..-18° 1.00..1.67 m/s"] and len(csv) == 3


def test_the_summary_round_trips_through_an_s3_store(s3_endpoint, settings, monkeypatch):
    """The same through the MinIO backend (moto's S3 server on loopback), as in production."""
    settings.MINIO_ENDPOINT, settings.MINIO_SECURE = s3_endpoint, False
    settings.MINIO_ACCESS_KEY, settings.MINIO_SECRET_KEY = S3_ACCESS_KEY, S3_SECRET_KEY
    settings.MINIO_BUCKET = f"deepracer-analysis-{uuid.uuid4().hex[:8]}"
    model = _model("on-s3")
    store, keys = get_store(), keys_for(model.pk)
    assert "Minio" in repr(store) or "minio" in repr(store).lower()
    track = analysis._track(model)
    for it in range(2):
        store.put_bytes(keys.simtrace(it), synthetic_iteration(
            track, iteration=it, episodes=4, num_actions=3, mean_steps=30), "text/csv")  # fmt: skip
        analysis.analysis_summary_update(model=model)
    assert store.exists(keys.prefix + analysis.SUMMARY_NAME)
    analysis.analysis_cache_clear()
    monkeypatch.setattr(analysis, "parse_simtrace", None)  # a chart that parsed would fail
    assert analysis.analysis_chart(model, "progress")["episodes"] == [4, 4]


@pytest.mark.django_db(transaction=True)
def test_charts_asked_for_at_once_parse_each_file_once(monkeypatch):
    """The page asks for five charts at once: a model without a summary is parsed once."""
    model = _model("asked-at-once")
    store, keys = get_store(), keys_for(model.pk)
    track = analysis._track(model)
    for it in range(3):
        store.put_bytes(keys.simtrace(it), synthetic_iteration(
            track, iteration=it, episodes=4, num_actions=3, mean_steps=30), "text/csv")  # fmt: skip
    parsed: list[int] = []
    real_parse = analysis.parse_simtrace
    monkeypatch.setattr(
        analysis, "parse_simtrace", lambda data: parsed.append(1) or real_parse(data)
    )

    def chart(name: str) -> dict:
        try:
            return analysis.analysis_chart(model, name)
        finally:
            connections.close_all()

    with ThreadPoolExecutor(5) as pool:
        results = list(pool.map(chart, ["progress", "heatmap", "episodes", "fastest", "actions"]))
    assert results[0]["iteration"] == [0, 1, 2] and len(results[2]["episode"]) == 12
    assert len(parsed) == 3
