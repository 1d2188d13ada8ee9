"""Server time of a model's analysis page and each chart's data, for a long run.

    .venv/bin/python bench/bench_analysis.py [--iterations 40] [--episodes 50] [--continuous]

Synthesises training logs on racecraft_oval (about 237,000 steps by default) in a temporary
store and database, one iteration file at a time, each followed by the training worker's
hook (``analysis_summary_update``: the file folded into the run's summary object), then
requests the page and every chart through Django's test client, as the browser does, three
ways:

- ``traces``: the old path, computing from the sim-traces: no summary in the store and
  nothing cached in the process, so the chart parses and sums every iteration file (the
  summary is not saved, so each chart pays it);
- ``uncached``: the summary in the store, nothing cached in the process (a fresh web
  process, or another process than the last one that read the model): median of 3;
- ``cached``: the summary kept by this process: median of 5.

The goal is each chart's data in at most 300 ms uncached. The last line is key=value pairs:
``max_chart_ms`` the slowest chart uncached, ``ratio`` the slowest chart from the traces over
it, ``hook_ms`` the mean time the worker's hook adds to an iteration.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
os.environ.setdefault("DJANGO_SETTINGS_MODULE", "console.settings")
GOAL_MS = 300.0
CONTINUOUS = {"steering_angle": {"low": -30.0, "high": 30.0}, "speed": {"low": 1.0, "high": 3.0}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--iterations", type=int, default=40)
    parser.add_argument("--episodes", type=int, default=50, help="episodes per iteration")
    parser.add_argument("--continuous", action="store_true", help="a continuous action space")
    args = parser.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="bench-analysis-"))
    os.environ["STORE_DIR"] = str(tmp / "store")
    os.environ["DATABASE_URL"] = f"sqlite:///{tmp / 'bench.sqlite3'}"

    import django

    django.setup()
    from django.conf import settings
    from django.contrib.auth import get_user_model
    from django.core.management import call_command
    from django.test import Client

    settings.ALLOWED_HOSTS = ["*"]
    call_command("migrate", verbosity=0)
    from training import services
    from training.analysis.synthetic import synthetic_iteration
    from training.services import analysis
    from training.services.checks import track_catalog
    from training.store import get_store, keys_for

    user = get_user_model().objects.create_user("bench", password="bench-pass-123")
    if args.continuous:
        actions, num_actions = CONTINUOUS, 0
        ranges = ((-30.0, 30.0), (1.0, 3.0))
    else:
        actions = [{"steering_angle": a, "speed": v} for a in (-30, -15, 0, 15, 30)
                   for v in (1, 2, 3)]  # fmt: skip
        num_actions, ranges = len(actions), None
    model = services.model_create(
        owner=user, name="long-run", track_id="racecraft_oval", action_space=actions,
        reward_function="def reward_function(params):\n    return 1.0\n", validate_reward=False,
    )  # fmt: skip
    track = track_catalog().load(model.track_id)
    store, keys = get_store(), keys_for(model.pk)
    steps, hook_ms = 0, []
    for it in range(args.iterations):
        data = synthetic_iteration(track, iteration=it, episodes=args.episodes,
                                   num_actions=num_actions, seed=7, continuous=ranges)  # fmt: skip
        steps += data.count(b"\n") - 1
        store.put_bytes(keys.simtrace(it), data, "text/csv")
        t0 = time.perf_counter()
        analysis.analysis_summary_update(model=model)  # what the worker does after each
        hook_ms.append((time.perf_counter() - t0) * 1000)
    summary_key = keys.prefix + analysis.SUMMARY_NAME
    summary_bytes = store.get_bytes(summary_key)

    client = Client()
    client.force_login(user)
    base = f"/models/{model.pk}/analysis/"
    last = args.iterations - 1
    urls = {
        "progress": base + "data/progress.json",
        "heatmap reward": base + "data/heatmap.json?kind=reward",
        "heatmap speed": base + "data/heatmap.json?kind=speed",
        "heatmap action": base + "data/heatmap.json?kind=action",
        "fastest laps": base + "data/fastest.json",
        "episodes": base + "data/episodes.json",
        "actions": base + "data/actions.json",
        "episode path": base + f"episode/{last}/{(last + 1) * args.episodes - 1}/",
        "progress csv": base + "data/progress.csv",
        "page": base,
    }

    def timed(url: str, *, before=None) -> float:
        if before is not None:
            before()
        t0 = time.perf_counter()
        response = client.get(url)
        elapsed = (time.perf_counter() - t0) * 1000
        assert response.status_code == 200, (url, response.status_code)
        return elapsed

    def without_summary() -> None:
        analysis.analysis_cache_clear()
        store.delete_prefix(keys.prefix + "analysis")

    saving = analysis._save
    analysis._save = lambda *a, **k: None  # the old path never saved what it computed
    traces = {name: timed(url, before=without_summary) for name, url in urls.items()}
    analysis._save = saving
    store.put_bytes(summary_key, summary_bytes)
    uncached = {
        name: statistics.median(timed(url, before=analysis.analysis_cache_clear) for _ in range(3))
        for name, url in urls.items()
    }
    cached = {name: statistics.median(timed(url) for _ in range(5)) for name, url in urls.items()}

    kind = "continuous" if args.continuous else f"{num_actions} discrete"
    print(f"{steps:,} logged steps in {args.iterations} iteration files ({args.episodes} "
          f"episodes each, {kind} actions); summary object {len(summary_bytes) / 1024:.0f} KiB; "
          f"load average {os.getloadavg()[0]:.1f}")  # fmt: skip
    print(f"{'chart':<16}{'traces ms':>11}{'uncached ms':>13}{'cached ms':>11}  "
          f"goal {GOAL_MS:.0f} ms uncached")  # fmt: skip
    for name in urls:
        mark = "ok" if uncached[name] <= GOAL_MS else "SLOW"
        print(
            f"{name:<16}{traces[name]:>11.1f}{uncached[name]:>13.1f}{cached[name]:>11.1f}  {mark}"
        )
    print(f"worker hook per iteration: mean {statistics.mean(hook_ms):.1f} ms, "
          f"max {max(hook_ms):.1f} ms")  # fmt: skip
    charts = [name for name in urls if name != "page"]
    slowest = max(uncached[n] for n in charts)
    slowest_cached = max(cached[n] for n in charts)
    slowest_traces = max(traces[n] for n in charts)
    print(
        f"steps={steps} max_chart_ms={slowest:.1f} max_cached_ms={slowest_cached:.1f} "
        f"traces_max_ms={slowest_traces:.0f} goal_ms={GOAL_MS:.0f} "
        f"ratio={slowest_traces / slowest:.1f} hook_ms={statistics.mean(hook_ms):.1f}"
    )


if __name__ == "__main__":
    main()
