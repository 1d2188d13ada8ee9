"""Live video of a training job as its viewers get it (issue 14): frames per second over the
run, the longest gap between two frames, and what 20 viewers cost the worker (encodes per
frame), for lockstep simulation (the console's default) and streamed simulation
(``RACECRAFT_SIMULATION=streams``).

    .venv/bin/python bench/bench_video.py [--seconds 45] [--iterations 1] [--max-seconds 180]
                                          [--viewers 20] [--episodes 20] [--modes lockstep,streams]

Each mode runs in a child process of its own: `manage.py up` on loopback (daphne, the Celery
workers, an embedded Redis) with a fresh SQLite database and store in a temporary folder, one
model with the console's default hyperparameters (``--episodes`` per policy update, 20 by
default) whose training starts at once. Then ``--viewers - 1`` plain browser websockets (one
Chromium page, the session cookie, counting the frame messages) and the model's page itself
(Chromium through Playwright, /usr/bin/chromium; every websocket message it receives is
counted and timed) watch the job. The window starts at the page's first frame and lasts
``--seconds`` and until ``--iterations`` policy updates were recorded or, streamed, the frames
have shown the new policy for 10 s (so that it holds an update and the handover to the new
policy), ``--max-seconds`` at most; the job is then stopped and its worker's frame counts
read from Redis (:func:`training.live.frame_counts`: frames it encoded once and sent once to
the job's group).

``--whole-run MINUTES`` watches a whole training run instead: the model's stop condition is
that many minutes and nobody stops the job. The window runs from the page's first frame to the
end of training (the job's start plus its minutes), so a pause anywhere, the last iteration's
included, shows as a gap; how long the first frame took after the job started is printed too.

Prints a table per mode, the gaps over 1 s with the frames on either side (what the worker
said it showed: phase, iteration, policy version), and last ``fps=``, ``max_gap_s=`` and
``encodes_per_frame=`` of the streamed mode with ``ratio=`` (streamed fps / lockstep fps, both
measured in this run). About 5 minutes on an idle 2-core machine (longer when a policy update
is slow); ``--iterations 0 --seconds 20 --episodes 4`` shortens it. The machine may be shared:
say so when you quote the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from bench_load import free_port, wait_http  # the console's start, as the load bench does

ROOT = Path(__file__).resolve().parents[1]
REWARD = """
def reward_function(params):
    if not params["all_wheels_on_track"]:
        return 1e-3
    return 1.0 - params["distance_from_center"] / params["track_width"]
"""
ACTIONS = [{"steering_angle": a, "speed": v} for a in (-30, 0, 30) for v in (1.0, 2.0)]
CHROMIUM = os.environ.get("RACECRAFT_TEST_CHROMIUM") or "/usr/bin/chromium"
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--no-first-run"]  # fmt: skip
FIRST_FRAME_TIMEOUT_S = 300.0
STOP_TIMEOUT_S = 180.0
GAP_REPORTED_S = 1.0
BUCKET_S = 10
HANDOVER_S = 10.0
RESULT = "RESULT "
# The extra viewers: plain websockets in one page, counting frame messages without parsing.
VIEWERS_JS = """([path, n]) => {
  window.viewerFrames = new Array(n).fill(0);
  window.viewerOpen = new Array(n).fill(false);
  for (let i = 0; i < n; i++) {
    const ws = new WebSocket(`ws://${location.host}${path}`);
    ws.onopen = () => { window.viewerOpen[i] = true; };
    ws.onmessage = (e) => {
      if (typeof e.data === "string" && e.data.startsWith('{"type": "frame"')) {
        window.viewerFrames[i] += 1;
      }
    };
  }
}"""


def run_mode(mode: str, args: argparse.Namespace) -> dict:
    """One mode in this process: the console up, a job trained and watched; a result dict."""
    var = Path(tempfile.mkdtemp(prefix=f"rc-bench-video-{mode}-"))
    port = free_port()
    env = {k: v for k, v in os.environ.items() if k not in ("DATABASE_URL", "REDIS_URL")}
    env.update({"RACECRAFT_VAR_DIR": str(var), "DEBUG": "0", "SECRET_KEY": "bench-only-key",
                "ALLOWED_HOSTS": "127.0.0.1,localhost", "LOG_LEVEL": "WARNING",
                "SECURE_SSL_REDIRECT": "0", "SECURE_HSTS_SECONDS": "0",
                "RACECRAFT_SIMULATION": mode,
                "DJANGO_SETTINGS_MODULE": "console.settings"})  # fmt: skip
    os.environ.clear()
    os.environ.update(env)
    log = open(var / "up.log", "w")  # noqa: SIM115 - closed at the end
    up = subprocess.Popen([sys.executable, "manage.py", "up", "--port", str(port)], cwd=ROOT,
                          env=env, stdout=log, stderr=subprocess.STDOUT)  # fmt: skip
    try:
        wait_http(port, up, timeout=180)
        return watch_job(mode, args, f"http://127.0.0.1:{port}")
    finally:
        up.send_signal(signal.SIGTERM)
        try:
            up.wait(90)
        except subprocess.TimeoutExpired:
            up.kill()
        log.close()
        print(f"[{mode}] console log: {var / 'up.log'}", file=sys.stderr)


def training_end(job, now_mono: float, now_wall: float) -> float:
    """The monotonic time at which ``job`` (started, with its ``max_minutes``) stops training:
    its recorded start plus its minutes, read off the wall clock at ``now_wall``."""
    end_wall = job.started_at.timestamp() + job.max_minutes * 60
    return now_mono + (end_wall - now_wall)


def watch_job(mode: str, args: argparse.Namespace, base: str) -> dict:
    import django

    django.setup()
    from django.contrib.auth import get_user_model
    from django.contrib.sessions.backends.db import SessionStore
    from playwright.sync_api import sync_playwright

    # Playwright's sync API keeps an event loop running in this thread; the ORM calls here are
    # still plain synchronous code.
    os.environ["DJANGO_ALLOW_ASYNC_UNSAFE"] = "true"
    from training import live, services
    from training.models import IterationMetric, JobStatus, TrainingJob

    user = get_user_model().objects.create_user("viewer")
    model = services.model_create(
        owner=user, name=f"video-{mode}", track_id="racecraft_oval", action_space=ACTIONS,
        reward_function=REWARD, validate_reward=False, seed=1,
        hyperparameters={"num_episodes_between_training": args.episodes},
        **({"max_minutes": args.whole_run} if args.whole_run else {}),
    )  # fmt: skip
    session = SessionStore()
    session["_auth_user_id"] = str(user.pk)
    session["_auth_user_backend"] = "django.contrib.auth.backends.ModelBackend"
    session["_auth_user_hash"] = user.get_session_auth_hash()
    session.create()
    job = services.training_start(model=model, user=user)
    group = live.job_group("training", job.pk)

    frames: list[tuple[float, dict]] = []  # (monotonic time, what the frame says it shows)

    def on_socket(ws) -> None:
        def on_message(payload: str | bytes) -> None:
            now = time.monotonic()
            if isinstance(payload, str) and payload.startswith('{"type": "frame"'):
                msg = json.loads(payload)
                keys = ("phase", "iteration", "version", "lap")
                frames.append((now, {k: msg[k] for k in keys if k in msg}))

        ws.on("framereceived", on_message)

    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        context = browser.new_context()
        context.add_cookies([{"name": "sessionid", "value": session.session_key, "url": base}])
        others = context.new_page()
        others.goto(f"{base}/")
        others.evaluate(VIEWERS_JS, [f"/ws/training/{job.pk}/", args.viewers - 1])
        page = context.new_page()
        page.on("websocket", on_socket)
        page.goto(f"{base}/models/{model.pk}/")

        started = time.monotonic()
        while not frames:
            if time.monotonic() - started > FIRST_FRAME_TIMEOUT_S:
                state = TrainingJob.objects.get(pk=job.pk)
                raise SystemExit(f"[{mode}] no frame in {FIRST_FRAME_TIMEOUT_S:.0f} s; job "
                                 f"{state.status} {state.error!r}")  # fmt: skip
            page.wait_for_timeout(200)
        t0 = frames[0][0]
        first_frame_s = t0 - started
        print(f"[{mode}] first frame {first_frame_s:.1f} s after the page opened", file=sys.stderr)
        finished_at: list[tuple[int, float]] = []  # (iteration, when its row was seen)
        seen = TrainingJob.objects.get(pk=job.pk).iterations
        if args.whole_run:
            return whole_run(mode, job, page, others, browser, frames, t0, first_frame_s,
                             args)  # fmt: skip
        # At least --seconds, and on until --iterations policy updates were recorded or, as
        # streamed workers record an update only after its evaluation laps, until the frames
        # have shown that policy version for HANDOVER_S: the handover is in the window.
        while True:
            elapsed = time.monotonic() - t0
            handed = [t for t, f in frames if f.get("version", -1) >= args.iterations]
            updated = seen >= args.iterations or (
                handed and time.monotonic() - handed[0] >= HANDOVER_S
            )
            if elapsed >= args.max_seconds or (elapsed >= args.seconds and updated):
                break
            page.wait_for_timeout(500)
            n = TrainingJob.objects.get(pk=job.pk).iterations
            if n != seen:
                finished_at.append((n, time.monotonic() - t0))
                seen = n
        t_stop = time.monotonic()
        window = [(t, f) for t, f in frames if t <= t_stop]
        # Off this thread: the stop's live message uses async_to_sync, and Playwright's
        # event loop runs in this one.
        latest = TrainingJob.objects.get(pk=job.pk)
        stopper = threading.Thread(target=services.job_stop, daemon=True,
                                   kwargs={"job": latest, "user": user})  # fmt: skip
        stopper.start()
        stopper.join(60)
        done = (JobStatus.COMPLETED, JobStatus.CANCELED, JobStatus.FAILED)
        while TrainingJob.objects.get(pk=job.pk).status not in done:
            if time.monotonic() - t_stop > STOP_TIMEOUT_S:
                raise SystemExit(f"[{mode}] the job did not stop in {STOP_TIMEOUT_S:.0f} s")
            page.wait_for_timeout(500)
        page.wait_for_timeout(2000)  # the last frames in flight
        received = others.evaluate("window.viewerFrames")
        opened = sum(others.evaluate("window.viewerOpen"))
        received.append(len(frames))
        browser.close()

    counts = {}
    for _ in range(20):  # the worker records them as its publisher closes
        counts = live.frame_counts(group)
        if counts:
            break
        time.sleep(0.5)
    metrics = list(IterationMetric.objects.filter(job=job).order_by("iteration").values(
        "iteration", "rollout_s", "update_s", "eval_s", "elapsed_s"))  # fmt: skip
    stats = video_stats(window, t0, t_stop, received=received, counts=counts)
    return {**stats, "mode": mode, "viewers_open": opened + 1, "iterations_at": finished_at,
            "metrics": metrics}  # fmt: skip


def whole_run(mode, job, page, others, browser, frames, t0, first_frame_s, args) -> dict:
    """``--whole-run``: watch until the job ends by itself; the window ends with training."""
    from training import live
    from training.models import IterationMetric, JobStatus, TrainingJob

    done = (JobStatus.COMPLETED, JobStatus.CANCELED, JobStatus.FAILED)
    limit = args.whole_run * 60 + STOP_TIMEOUT_S + FIRST_FRAME_TIMEOUT_S
    while True:
        state = TrainingJob.objects.get(pk=job.pk)
        if state.status in done:
            break
        if time.monotonic() - t0 > limit:
            raise SystemExit(f"[{mode}] the job did not end in {limit:.0f} s")
        page.wait_for_timeout(1000)
    page.wait_for_timeout(2000)  # the last frames in flight
    t_stop = training_end(state, time.monotonic(), time.time())
    since_job = t0 - (t_stop - state.max_minutes * 60)  # from the worker's start of the job
    received = others.evaluate("window.viewerFrames")
    opened = sum(others.evaluate("window.viewerOpen"))
    received.append(len(frames))
    browser.close()
    if state.status != JobStatus.COMPLETED:
        raise SystemExit(f"[{mode}] the job ended {state.status}: {state.error!r}")
    window = [(t, f) for t, f in frames if t0 <= t <= t_stop]
    counts = live.frame_counts(live.job_group("training", job.pk))
    metrics = list(IterationMetric.objects.filter(job=job).order_by("iteration").values(
        "iteration", "rollout_s", "update_s", "eval_s", "elapsed_s"))  # fmt: skip
    stats = video_stats(window, t0, t_stop, received=received, counts=counts)
    return {**stats, "mode": mode, "viewers_open": opened + 1, "iterations_at": [],
            "metrics": metrics, "first_frame_s": first_frame_s,
            "first_frame_after_job_s": since_job}  # fmt: skip


def video_stats(window: list[tuple[float, dict]], t0: float, t_stop: float, *,
                received: list[int], counts: dict[str, int]) -> dict:  # fmt: skip
    """What the viewers got: frames/s over the window ``[t0, t_stop]`` (monotonic seconds),
    the gaps (the last one runs to the window's end), and the worker's encodes per frame a
    viewer received (``counts`` from :func:`training.live.frame_counts`)."""
    gaps = [(b - a, a - t0, fa, fb) for (a, fa), (b, fb) in zip(window, window[1:], strict=False)]
    last_t, last_f = window[-1]
    gaps.append((t_stop - last_t, last_t - t0, last_f, {"end": "window"}))
    longest = max(gaps, key=lambda g: g[0])
    span = t_stop - t0
    encoded = counts.get("encoded", 0)
    return {
        "window_s": span, "frames": len(window), "fps": len(window) / span,
        "max_gap_s": longest[0], "encoded": encoded, "sent": counts.get("sent", 0),
        "received": received,
        "encodes_per_frame": encoded / statistics.mean(received) if any(received) else 0.0,
        "long_gaps": [g for g in gaps if g[0] > GAP_REPORTED_S],
        "timeline": timeline(window, t0, span),
    }  # fmt: skip


def timeline(window: list[tuple[float, dict]], t0: float, span: float) -> list[list]:
    """Frames per ``BUCKET_S`` of the window: ``[start s, fps, what the frames showed]``."""
    rows = []
    for start in range(0, int(span), BUCKET_S):
        inside = [f for t, f in window if start <= t - t0 < start + BUCKET_S]
        length = min(BUCKET_S, span - start)
        kinds = sorted({shown({k: v for k, v in f.items() if k != "lap"}) for f in inside})
        rows.append([start, len(inside) / length, ", ".join(kinds)])
    return rows


# ---------------------------------------------------------------------------- the report
def shown(frame: dict) -> str:
    if "end" in frame:
        return "(end of window)"
    parts = [frame.get("phase", "-")]
    if "iteration" in frame:
        parts.append(f"it {frame['iteration']}")
    if "version" in frame:
        parts.append(f"v{frame['version']}")
    if frame.get("lap"):
        parts.append(f"lap {frame['lap']}")
    return " ".join(parts)


def report(results: list[dict], args: argparse.Namespace) -> None:
    if args.whole_run:
        span = f"a whole {args.whole_run}-minute training run, from the first frame to its end"
    else:
        span = (f"at least {args.seconds:.0f} s and {args.iterations} update(s), at most "
                f"{args.max_seconds:.0f} s")  # fmt: skip
    print(f"\nlive video, {args.viewers} viewers (1 Chromium model page + "
          f"{args.viewers - 1} websockets), window from the first frame: {span}; "
          f"{args.episodes} episodes per update")  # fmt: skip
    print(f"{'mode':<10}{'window s':>9}{'frames':>8}{'fps':>7}{'max gap s':>10}{'encoded':>9}"
          f"{'sent':>7}{'recv/viewer min/mean/max':>26}{'enc/frame':>10}")  # fmt: skip
    for r in results:
        recv = r["received"]
        spread = f"{min(recv)}/{statistics.mean(recv):.0f}/{max(recv)}"
        print(f"{r['mode']:<10}{r['window_s']:>9.1f}{r['frames']:>8}{r['fps']:>7.1f}"
              f"{r['max_gap_s']:>10.2f}{r['encoded']:>9}{r['sent']:>7}{spread:>26}"
              f"{r['encodes_per_frame']:>10.2f}")  # fmt: skip
    for r in results:
        if "first_frame_after_job_s" in r:
            print(f"\n[{r['mode']}] first frame {r['first_frame_after_job_s']:.1f} s after the "
                  f"worker started the job, {r['first_frame_s']:.1f} s after the page "
                  "opened")  # fmt: skip
        print(f"\n[{r['mode']}] viewers connected: {r['viewers_open']}/{args.viewers}; "
              f"iterations seen at (s into the window): "
              f"{', '.join(f'{n}@{t:.0f}' for n, t in r['iterations_at']) or 'none'}")  # fmt: skip
        for m in r["metrics"]:
            print(f"  iteration {m['iteration']}: rollout {m['rollout_s']:.1f} s, update "
                  f"{m['update_s']:.1f} s, evaluation {m['eval_s']:.1f} s")  # fmt: skip
        for start, fps, kinds in r["timeline"]:
            print(f"  {start:4d}-{start + BUCKET_S:<4d}s {fps:5.1f} fps  {kinds}")
        gaps = r["long_gaps"]
        print(f"  gaps over {GAP_REPORTED_S:.0f} s: {len(gaps)}")
        for length, at, before, after in sorted(gaps, reverse=True)[:8]:
            print(f"    {length:5.2f} s at {at:6.1f} s: {shown(before)} -> {shown(after)}")
    print(f"\n{last_line(results)} viewers={args.viewers}")


def last_line(results: list[dict]) -> str:
    """``fps= max_gap_s= encodes_per_frame=`` of the streamed mode (else the last one run) and
    ``ratio=`` its fps over lockstep's, measured in the same run (0 without lockstep)."""
    by_mode = {r["mode"]: r for r in results}
    head = by_mode.get("streams") or results[-1]
    base = by_mode.get("lockstep")
    base = base if base is not head else None
    ratio = head["fps"] / base["fps"] if base and base["fps"] else 0.0
    line = (f"fps={head['fps']:.2f} max_gap_s={head['max_gap_s']:.2f} "
            f"encodes_per_frame={head['encodes_per_frame']:.3f} ratio={ratio:.2f} "
            f"mode={head['mode']} window_s={head['window_s']:.0f}")  # fmt: skip
    if base:
        line += (f" baseline_fps={base['fps']:.2f} baseline_max_gap_s={base['max_gap_s']:.2f}"
                 f" baseline_encodes_per_frame={base['encodes_per_frame']:.3f}")  # fmt: skip
    return line


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=45.0, help="shortest window per mode")
    parser.add_argument("--iterations", type=int, default=1,
                        help="the window lasts until this many updates were recorded")  # fmt: skip
    parser.add_argument("--max-seconds", type=float, default=180.0, help="longest window")
    parser.add_argument("--viewers", type=int, default=20)
    parser.add_argument("--episodes", type=int, default=20, help="episodes per policy update")
    parser.add_argument("--modes", default="lockstep,streams")
    parser.add_argument("--whole-run", type=int, default=0, metavar="MINUTES",
                        help="watch a whole training run of this many minutes")  # fmt: skip
    parser.add_argument("--one-mode", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one_mode:  # a child: one mode, its result as the last line
        print(RESULT + json.dumps(run_mode(args.one_mode, args)), flush=True)
        return
    results = []
    for mode in args.modes.split(","):
        out = subprocess.run(
            [sys.executable, __file__, "--one-mode", mode, "--seconds", str(args.seconds),
             "--viewers", str(args.viewers), "--episodes", str(args.episodes),
             "--iterations", str(args.iterations), "--max-seconds", str(args.max_seconds),
             "--whole-run", str(args.whole_run)],
            cwd=ROOT, stdout=subprocess.PIPE, text=True, check=False,
        )  # fmt: skip
        lines = [x for x in out.stdout.splitlines() if x.startswith(RESULT)]
        if out.returncode or not lines:
            raise SystemExit(f"the {mode} run failed ({out.returncode}):\n{out.stdout[-3000:]}")
        results.append(json.loads(lines[-1][len(RESULT) :]))
    report(results, args)


if __name__ == "__main__":
    main()
