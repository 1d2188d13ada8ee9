"""Web page times under load: 50 simulated users browse, validate reward functions, start (and
stop) jobs and watch a job's page, first on an idle console (the baseline), then while 2 jobs
train - all on this machine, through `manage.py up` (web, workers, beat, embedded Redis) on
loopback, with a fresh SQLite database and store in a temporary folder.

    .venv/bin/python bench/bench_load.py [--users 50] [--seconds 40] [--think 1.0,3.0]

Each user signs in (a session made directly in the database), then loops: a page (home, model
list, a model's page - where its job shows - twice as often, the track gallery), sometimes
(--validate-share, 3%) the Validate button (POST /api/reward/validate, which runs the reward
in a sandboxed interpreter), and while the 2 jobs train, sometimes (4%) Train then Stop on a
model of its own (its job stays queued behind the 2 trainings and is canceled), with a random
think time between requests. Page time is the time to the last byte of a GET page.
Prints a table per phase and, last, ``p95_ms=`` (pages while training), ``errors=`` (any
5xx, connection error or unexpected status, both phases) and the ratio to the idle baseline.
Bounded in time: about 2 x --seconds plus start-up (the trainings are stopped at the end).
The machine may be shared: say so when you quote the figures.
"""

from __future__ import annotations

import argparse
import http.client
import os
import random
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections import defaultdict
from pathlib import Path
from urllib.parse import urlencode

ROOT = Path(__file__).resolve().parents[1]
REWARD = """
def reward_function(params):
    if not params["all_wheels_on_track"]:
        return 1e-3
    return 1.0 - params["distance_from_center"] / params["track_width"]
"""
ACTIONS = [{"steering_angle": a, "speed": v} for a in (-30, 0, 30) for v in (1.0, 2.0)]
PAGE_KINDS = ("home", "models", "model", "model", "tracks")
args_validate_share = [0.03]
"""Share of a user's actions that press Validate (set from --validate-share)."""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def percentile(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    ordered = sorted(values)
    k = max(0, min(len(ordered) - 1, round(q / 100 * (len(ordered) - 1))))
    return ordered[k]


class User(threading.Thread):
    """One simulated user with its own session, keep-alive connection and models."""

    def __init__(self, port: int, cookie: str, csrf: str, own_models: list[int],
                 watch: int, deadline: float, think: tuple[float, float],
                 record, seed: int, starts: bool) -> None:  # fmt: skip
        super().__init__(daemon=True)
        self.port, self.cookie, self.csrf = port, cookie, csrf
        self.own_models, self.watch = own_models, watch
        self.deadline, self.think, self.record = deadline, think, record
        self.rng = random.Random(seed)
        self.starts = starts
        self.conn: http.client.HTTPConnection | None = None

    def request(self, kind: str, method: str, path: str, body: str | None = None,
                content_type: str = "application/x-www-form-urlencoded") -> None:  # fmt: skip
        headers = {"Cookie": self.cookie, "Host": "127.0.0.1"}
        if method == "POST":
            headers.update({"X-CSRFToken": self.csrf, "Content-Type": content_type})
        started = time.perf_counter()
        status, error = 0, ""
        for attempt in range(2):  # one retry on a stale keep-alive connection
            try:
                if self.conn is None:
                    self.conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=60)
                self.conn.request(method, path, body=body, headers=headers)
                response = self.conn.getresponse()
                response.read()
                status = response.status
                if response.getheader("Connection", "").lower() == "close":
                    self.conn.close()
                    self.conn = None
                break
            except (OSError, http.client.HTTPException) as exc:
                if self.conn is not None:
                    self.conn.close()
                self.conn = None
                error = type(exc).__name__
                if attempt:
                    break
        elapsed_ms = (time.perf_counter() - started) * 1000
        ok = status in (200, 202, 302, 400, 429) and not (status == 0 and error)
        self.record(kind, elapsed_ms, ok, f"{status} {error}".strip())

    def run(self) -> None:
        try:
            self._loop()
        except Exception as exc:  # noqa: BLE001 - a crashed user is an error, not a hang
            self.record("user-crashed", 0.0, False, repr(exc))

    def _loop(self) -> None:
        model = self.watch
        while time.monotonic() < self.deadline:
            roll = self.rng.random()
            if roll < args_validate_share[0]:
                source = REWARD if self.rng.random() < 0.8 else "def reward_function(p):\n  retur"
                body = urlencode(
                    {"source": source, "track": "racecraft_oval", "direction": "native"}
                )
                self.request("api:validate", "POST", "/api/reward/validate", body)
            elif roll < args_validate_share[0] + 0.04 and self.own_models and self.starts:
                mine = self.rng.choice(self.own_models)
                self.request("post:train", "POST", f"/models/{mine}/train/", "")
                self.request("page:model", "GET", f"/models/{mine}/")
                self.stop_own_job(mine)
            else:
                kind = self.rng.choice(PAGE_KINDS)
                path = {"home": "/", "models": "/models/", "model": f"/models/{model}/",
                        "tracks": "/tracks/"}[kind]  # fmt: skip
                self.request(f"page:{kind}", "GET", path)
            time.sleep(self.rng.uniform(*self.think))
        if self.conn is not None:
            self.conn.close()

    def stop_own_job(self, model_id: int) -> None:
        from training.models import JobStatus, TrainingJob

        job = (TrainingJob.objects.filter(model_id=model_id, status=JobStatus.QUEUED)
               .order_by("-pk").first())  # fmt: skip
        if job is not None:
            self.request("post:stop", "POST", f"/jobs/training/{job.pk}/stop/", "")


class Recorder:
    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.times: dict[str, list[float]] = defaultdict(list)
        self.errors: dict[str, list[str]] = defaultdict(list)

    def __call__(self, kind: str, ms: float, ok: bool, what: str) -> None:
        with self.lock:
            self.times[kind].append(ms)
            if not ok:
                self.errors[kind].append(what)

    def pages(self) -> list[float]:
        return [t for kind, ts in self.times.items() if kind.startswith("page:") for t in ts]

    def error_count(self) -> int:
        return sum(len(e) for e in self.errors.values())


def print_table(title: str, rec: Recorder, seconds: float) -> None:
    print(f"\n{title}")
    print(f"{'request':<16}{'count':>7}{'p50 ms':>9}{'p95 ms':>9}{'max ms':>9}{'errors':>8}")
    for kind in sorted(rec.times):
        ts = rec.times[kind]
        print(f"{kind:<16}{len(ts):>7}{statistics.median(ts):>9.0f}{percentile(ts, 95):>9.0f}"
              f"{max(ts):>9.0f}{len(rec.errors[kind]):>8}")  # fmt: skip
    pages = rec.pages()
    total = sum(len(t) for t in rec.times.values())
    print(f"{'all pages':<16}{len(pages):>7}{statistics.median(pages):>9.0f}"
          f"{percentile(pages, 95):>9.0f}{max(pages):>9.0f}{'':>8}")  # fmt: skip
    print(f"requests/s {total / seconds:.1f}")
    for kind, errs in rec.errors.items():
        if errs:
            print(f"  errors in {kind}: {sorted(set(errs))[:5]}")


def wait_http(port: int, proc: subprocess.Popen, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise SystemExit(f"manage.py up exited with {proc.returncode}")
        try:
            conn = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
            conn.request("GET", "/")
            if conn.getresponse().status < 500:
                return
        except OSError:
            pass
        time.sleep(0.5)
    raise SystemExit("the console did not answer")


def run_phase(args, port: int, users: list[tuple], title: str, starts: bool) -> Recorder:
    rec = Recorder()
    deadline = time.monotonic() + args.seconds
    think = tuple(float(x) for x in args.think.split(","))
    threads = [User(port, cookie, csrf, own, watch, deadline, think, rec, seed=i, starts=starts)
               for i, (cookie, csrf, own, watch) in enumerate(users)]  # fmt: skip
    for i, t in enumerate(threads):
        t.start()
        time.sleep(think[0] / len(threads) * (i % 5))  # spread the first requests a little
    for t in threads:
        t.join(args.seconds + 120)
    print_table(title, rec, args.seconds)
    return rec


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--users", type=int, default=50)
    parser.add_argument("--seconds", type=float, default=40.0, help="per phase")
    parser.add_argument("--think", default="1.0,3.0", help="think time range, seconds")
    parser.add_argument("--trainings", type=int, default=2)
    parser.add_argument(
        "--validate-share",
        type=float,
        default=0.03,
        help="share of actions that press Validate (a sandboxed run)",
    )
    args = parser.parse_args()
    args_validate_share[0] = args.validate_share

    var = Path(tempfile.mkdtemp(prefix="rc-bench-"))
    port = free_port()
    env = {k: v for k, v in os.environ.items() if k not in ("DATABASE_URL", "REDIS_URL")}
    env.update({"RACECRAFT_VAR_DIR": str(var), "DEBUG": "0", "SECRET_KEY": "bench-only-key",
                "ALLOWED_HOSTS": "127.0.0.1,localhost", "LOG_LEVEL": "WARNING",
                "RACECRAFT_MAX_ACTIVE_JOBS_PER_USER": "3",
                # plain HTTP on loopback (production sits behind a TLS proxy)
                "SECURE_SSL_REDIRECT": "0", "SECURE_HSTS_SECONDS": "0",
                "RACECRAFT_VALIDATIONS_PER_USER": "50"})  # fmt: skip
    os.environ.update(env)
    for key in ("DATABASE_URL", "REDIS_URL"):
        os.environ.pop(key, None)
    os.environ.setdefault("DJANGO_SETTINGS_MODULE", "console.settings")
    log = open(var / "up.log", "w")  # noqa: SIM115 - closed at the end
    up = subprocess.Popen([sys.executable, "manage.py", "up", "--port", str(port)], cwd=ROOT,
                          env=env, stdout=log, stderr=subprocess.STDOUT)  # fmt: skip
    try:
        wait_http(port, up, timeout=180)
        import django

        django.setup()
        from django.contrib.auth import get_user_model
        from django.contrib.sessions.backends.db import SessionStore

        from training import services
        from training.models import JobStatus, TrainingJob

        User_ = get_user_model()
        trainer = User_.objects.create_user("trainer")
        trained = []
        for i in range(args.trainings):
            trained.append(services.model_create(
                owner=trainer, name=f"trained-{i}", track_id="racecraft_oval",
                action_space=ACTIONS, reward_function=REWARD, validate_reward=False,
                hyperparameters={"num_episodes_between_training": 4, "batch_size": 32},
                max_minutes=30, seed=i,
            ))  # fmt: skip
        users = []
        csrf = "b" * 32
        for i in range(args.users):
            user = User_.objects.create_user(f"user{i}")  # no password: no hashing cost
            own = [services.model_create(owner=user, name=f"m{i}-{k}", track_id="racecraft_oval",
                                         action_space=ACTIONS, reward_function=REWARD,
                                         validate_reward=False).pk for k in range(2)]  # fmt: skip
            session = SessionStore()
            session["_auth_user_id"] = str(user.pk)
            session["_auth_user_backend"] = "django.contrib.auth.backends.ModelBackend"
            session["_auth_user_hash"] = user.get_session_auth_hash()
            session.create()
            cookie = f"sessionid={session.session_key}; csrftoken={csrf}"
            users.append((cookie, csrf, own, None))
        # Everyone watches the page of one of their own models (where its job shows).
        users = [(c, t, own, own[0]) for c, t, own, _ in users]

        sized = f"({args.users} users, {args.seconds:.0f} s)"
        # Users start (and stop) jobs only while the trainings hold every training process:
        # on an idle console their jobs would start training and the baseline would not be idle.
        idle = run_phase(args, port, users, f"idle console {sized}", starts=False)
        jobs = [services.training_start(model=m, user=trainer) for m in trained]
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline:
            states = list(TrainingJob.objects.filter(pk__in=[j.pk for j in jobs])
                          .values_list("status", flat=True))  # fmt: skip
            if all(s == JobStatus.IN_PROGRESS for s in states):
                break
            time.sleep(1)
        else:
            raise SystemExit(f"the trainings did not start: {states}")
        time.sleep(5)  # past the start-up: rollouts and updates running
        busy = run_phase(
            args, port, users, f"while {args.trainings} jobs train {sized}", starts=True
        )
        iterations = list(TrainingJob.objects.filter(pk__in=[j.pk for j in jobs])
                          .values_list("iterations", flat=True))  # fmt: skip
        for job in jobs:
            try:
                services.job_stop(job=TrainingJob.objects.get(pk=job.pk), user=trainer)
            except services.ServiceError:
                pass
        base95, busy95 = percentile(idle.pages(), 95), percentile(busy.pages(), 95)
        errors = idle.error_count() + busy.error_count()
        print(f"\ntraining iterations finished during the run: {iterations}")
        print(f"p95_ms={busy95:.0f} errors={errors} baseline_p95_ms={base95:.0f} "
              f"ratio={busy95 / base95:.2f} p50_ms={statistics.median(busy.pages()):.0f} "
              f"users={args.users}")  # fmt: skip
    finally:
        up.send_signal(signal.SIGTERM)
        try:
            up.wait(90)
        except subprocess.TimeoutExpired:
            up.kill()
        log.close()


if __name__ == "__main__":
    main()
