"""Server time of a model's analysis page and its charts' data, for a long run.

    .venv/bin/python bench/bench_analysis.py [--iterations 40] [--episodes 50]

Synthesises training logs on racecraft_oval (about 200,000 steps by default) in a temporary
store and database, then requests the page and every chart through Django's test client, as
the browser does: first with a cold cache (the first chart parses every iteration file), then
warm (the median of 5). The goal is each chart's data in at most 300 ms. The last line is
key=value pairs; ``ratio`` is the cold first chart's time over the slowest warm chart's.
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--iterations", type=int, default=40)
    parser.add_argument("--episodes", type=int, default=50, help="episodes per iteration")
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
    from training.services.checks import track_catalog
    from training.store import get_store, keys_for

    user = get_user_model().objects.create_user("bench", password="bench-pass-123")
    actions = [{"steering_angle": a, "speed": v} for a in (-30, -15, 0, 15, 30) for v in (1, 2, 3)]
    model = services.model_create(
        owner=user, name="long-run", track_id="racecraft_oval", action_space=actions,
        reward_function="def reward_function(params):\n    return 1.0\n", validate_reward=False,
    )  # fmt: skip
    track = track_catalog().load(model.track_id)
    store, keys = get_store(), keys_for(model.pk)
    steps = 0
    for it in range(args.iterations):
        data = synthetic_iteration(track, iteration=it, episodes=args.episodes,
                                   num_actions=len(actions), seed=7)  # fmt: skip
        steps += data.count(b"\n") - 1
        store.put_bytes(keys.simtrace(it), data, "text/csv")

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

    def timed(url: str) -> float:
        t0 = time.perf_counter()
        response = client.get(url)
        elapsed = (time.perf_counter() - t0) * 1000
        assert response.status_code == 200, (url, response.status_code)
        return elapsed

    cold = {name: timed(url) for name, url in urls.items()}
    warm = {name: statistics.median(timed(url) for _ in range(5)) for name, url in urls.items()}
    print(f"{steps:,} logged steps in {args.iterations} iteration files "
          f"({args.episodes} episodes each); shared machine, times vary")  # fmt: skip
    print(f"{'chart':<16}{'cold ms':>10}{'warm ms':>10}  goal {GOAL_MS:.0f} ms")
    for name in urls:
        mark = "ok" if warm[name] <= GOAL_MS else "SLOW"
        print(f"{name:<16}{cold[name]:>10.1f}{warm[name]:>10.1f}  {mark}")
    first = next(iter(urls))
    slowest = max(v for k, v in warm.items() if k != "page")
    print(
        f"steps={steps} cold_first_ms={cold[first]:.0f} warm_max_ms={slowest:.1f} "
        f"goal_ms={GOAL_MS:.0f} ratio={cold[first] / slowest:.1f}"
    )


if __name__ == "__main__":
    main()
