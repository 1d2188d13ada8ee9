"""Issue 25: a web host and worker hosts that share no disk. Three "machines", each with its own
RACECRAFT_VAR_DIR, TMPDIR and tracks folder: the web (daphne, as ``manage.py up`` starts it), a
worker machine (Celery workers for training, evaluation, interactive and default) and a
simulation machine (a Celery worker on the ``simulation`` queue). Between them only what
production shares: one PostgreSQL (the test database), one Redis, and an S3 object store
(moto's server, the console's MinIO backend).

Where the kernel allows it, every process runs in a private mount namespace with an empty,
read-only tmpfs over the other machines' folders, so that it provably cannot read (or write)
them; where ``unshare`` is refused, the machines only have separate folders, and the test says
so with a warning.

Through HTTP, as a logged-in user: a track is uploaded on the Tracks page (a small loop made
here), two models are created on it, one trains in lockstep, the other in streamed mode
(``RACECRAFT_SIMULATION=streams`` with ``RACECRAFT_REMOTE_ROLLOUT_SLOTS=1``: its episodes come
from the simulation machine), each is stopped after its first iteration; the first is then
evaluated (and its video watched), its car archive downloaded and imported back as a new model,
and its analysis opened. In the end every machine holds the track, which it got by its content
from the database, and nothing else: checkpoints, logs, exports and uploads went through the
store. (A simulation worker that drove the trainer's track folder instead of its own, as
``simulate_here`` once could have, fails here only because that folder is hidden.)

``RACECRAFT_TEST_NO_NAMESPACES=1`` runs it as where ``unshare`` is refused.
"""

from __future__ import annotations

import hashlib
import html
import io
import json
import logging
import os
import re
import shlex
import shutil
import socket
import subprocess
import sys
import tarfile
import time
import uuid
import warnings
from collections.abc import Callable, Iterator
from contextlib import ExitStack
from dataclasses import dataclass
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
import requests
from django.contrib.auth import get_user_model

from console.celery import app as celery_app
from tests.support import (
    CENTRE_LINE_REWARD,
    S3_ACCESS_KEY,
    S3_SECRET_KEY,
    database_url,
    free_port,
    stop_child,
)
from training.models import EvaluationJob, JobStatus, TrackFile, TrainingJob
from training.store import get_store, keys_for

pytestmark = [pytest.mark.slow, pytest.mark.django_db(transaction=True),
              pytest.mark.timeout(1800)]  # fmt: skip

ROOT = Path(__file__).resolve().parents[2]
MACHINES = ("web", "worker", "sim")
TRACK_ID = "e2e_loop"
PASSWORD = "correct-horse-battery-9"
DEADLINE_S = 900.0
"""How long any one step may take on a loaded machine (never a timing assertion)."""
START_S = 180.0
NO_NAMESPACES = "RACECRAFT_TEST_NO_NAMESPACES"


def _loop_track() -> bytes:
    """A DeepRacer waypoint file (N x 6: centre, inner, outer), a 6.4 x 4 m ellipse 1 m wide,
    closed: made here, so that its content is this test's own."""
    t = np.append(np.linspace(0, 2 * np.pi, 80, endpoint=False), 0.0)
    centre = np.column_stack([3.2 * np.cos(t), 2.0 * np.sin(t)])
    normal = np.column_stack([2.0 * np.cos(t), 3.2 * np.sin(t)])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    buffer = io.BytesIO()
    np.save(buffer, np.hstack([centre, centre - 0.5 * normal, centre + 0.5 * normal]))
    return buffer.getvalue()


# ---- the machines' processes


def _namespaces_refused(probe: Path) -> str:
    """Why this machine cannot hide folders from a process ('' when it can)."""
    if os.environ.get(NO_NAMESPACES):
        return f"{NO_NAMESPACES} is set"
    if not shutil.which("unshare"):
        return "no unshare command"
    probe.mkdir(parents=True, exist_ok=True)
    result = subprocess.run(
        ["unshare", "--mount", "--propagation", "private", "sh", "-c",
         f"mount -t tmpfs -o ro,size=4k racecraft-hidden {shlex.quote(str(probe))}"],
        capture_output=True, text=True, timeout=30,
    )  # fmt: skip
    return "" if result.returncode == 0 else (result.stderr.strip() or f"rc {result.returncode}")


def _hidden_from(argv: list[str], hide: list[Path]) -> list[str]:
    """``argv`` in a private mount namespace where each folder of ``hide`` is an empty,
    read-only tmpfs (the command is exec'd: the process id is the command's)."""
    mounts = "".join(f"mount -t tmpfs -o ro,size=4k racecraft-hidden {shlex.quote(str(p))} && "
                     for p in hide)  # fmt: skip
    return ["unshare", "--mount", "--propagation", "private", "sh", "-c",
            mounts + 'exec "$@"', "sh", *argv]  # fmt: skip


@dataclass
class Process:
    name: str
    machine: str
    popen: subprocess.Popen
    log_path: Path
    ready: Callable[[], bool]
    node: str = ""


class Machines:
    """The three machines' folders and processes; ``logs()`` for failure messages."""

    def __init__(self, base: Path, env: dict[str, str], stack: ExitStack) -> None:
        self.base, self.stack, self.processes = base, stack, []
        self.roots = {m: base / m for m in MACHINES}
        self.envs = {}
        for machine, root in self.roots.items():
            for sub in ("var", "tmp"):
                (root / sub).mkdir(parents=True)
            self.envs[machine] = {**env, "RACECRAFT_VAR_DIR": str(root / "var"),
                                  "TMPDIR": str(root / "tmp"),
                                  "RACECRAFT_TRACKS_DIR": str(root / "var" / "tracks")}  # fmt: skip
        self.refused = _namespaces_refused(base / "probe")
        if self.refused:
            warnings.warn(
                f"mount namespaces refused ({self.refused}): the machines have separate "
                "folders, but each process could still read the others'",
                stacklevel=2,
            )

    def start(self, name: str, machine: str, argv: list[str], ready: Callable[[], bool],
              **extra_env: str) -> Process:  # fmt: skip
        if not self.refused:
            argv = _hidden_from(argv, [r for m, r in self.roots.items() if m != machine])
        log_path = self.base / f"{name}.log"
        with open(log_path, "w") as log:
            popen = subprocess.Popen(argv, cwd=ROOT, env={**self.envs[machine], **extra_env},
                                     stdout=log, stderr=subprocess.STDOUT)  # fmt: skip
        process = Process(name, machine, popen, log_path, ready)
        self.processes.append(process)
        self.stack.callback(stop_child, popen)
        return process

    def worker(self, name: str, machine: str, queues: str, concurrency: int = 1,
               **extra_env: str) -> Process:  # fmt: skip
        node = f"e2e-{name}-{uuid.uuid4().hex[:6]}"
        argv = [sys.executable, "-m", "celery", "-A", "console", "worker", "-Q", queues,
                "-c", str(concurrency), "-n", f"{node}@%h", "--without-gossip",
                "--without-mingle", "-l", "INFO"]  # fmt: skip

        def answers() -> bool:
            replies = celery_app.control.ping(timeout=1.0)
            return any(w.startswith(f"{node}@") for reply in replies for w in reply)

        process = self.start(name, machine, argv, answers, **extra_env)
        process.node = node
        return process

    def web(self) -> tuple[Process, str]:
        port = free_port()
        argv = [sys.executable, "-m", "daphne", "-b", "127.0.0.1", "-p", str(port),
                "console.asgi:application"]  # fmt: skip

        def listens() -> bool:
            with socket.socket() as s:
                return s.connect_ex(("127.0.0.1", port)) == 0

        return self.start("web", "web", argv, listens), f"http://127.0.0.1:{port}"

    def wait_ready(self, *processes: Process) -> None:
        for process in processes:
            self.wait(process.ready, START_S, f"{process.name} to start")

    def logs(self) -> str:
        return "\n".join(f"---- {p.name} (exit {p.popen.poll()}):\n{p.log_path.read_text()[-3000:]}"
                         for p in self.processes)  # fmt: skip

    def wait(self, predicate: Callable[[], object], timeout: float, what: str) -> object:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            dead = [p.name for p in self.processes if p.popen.poll() is not None]
            if dead:
                pytest.fail(f"{', '.join(dead)} exited while waiting for {what}\n{self.logs()}")
            value = predicate()
            if value:
                return value
            time.sleep(1.0)
        pytest.fail(f"timed out after {timeout:.0f} s waiting for {what}\n{self.logs()}")

    def check_hidden(self) -> None:
        """Each process finds the other machines' folders empty (through /proc/<pid>/root,
        its own view of the file system), while they are not."""
        if self.refused:
            return
        for process in self.processes:
            for machine, root in self.roots.items():
                if machine != process.machine:
                    seen = os.listdir(f"/proc/{process.popen.pid}/root{root}")
                    assert seen == [], f"{process.name} sees {machine}'s files: {seen}"


# ---- the browser's side: a session, forms as the pages render them


class FormFields(HTMLParser):
    """The fields of the form with id ``form_id`` as a browser submits them without scripts:
    inputs (checked boxes only), each select's selected option, textareas."""

    def __init__(self, form_id: str) -> None:
        super().__init__()
        self.form_id, self.inside, self.fields = form_id, False, []
        self._select: list | None = None
        self._textarea: list | None = None

    def handle_starttag(self, tag: str, attrs: list) -> None:
        a = dict(attrs)
        if tag == "form":
            self.inside = a.get("id") == self.form_id
        elif not self.inside:
            return
        elif tag == "input" and a.get("name"):
            kind = a.get("type", "text")
            if kind not in ("submit", "button", "file", "reset") and (
                kind not in ("checkbox", "radio") or "checked" in a
            ):
                self.fields.append((a["name"], a.get("value") or ""))
        elif tag == "select" and a.get("name"):
            self._select = [a["name"], None, None]
        elif tag == "option" and self._select is not None and "value" in a:
            if self._select[1] is None:
                self._select[1] = a["value"]
            if "selected" in a:
                self._select[2] = a["value"]
        elif tag == "textarea" and a.get("name"):
            self._textarea = [a["name"], ""]

    def handle_endtag(self, tag: str) -> None:
        if tag == "form":
            self.inside = False
        elif tag == "select" and self._select is not None:
            name, first, chosen = self._select
            self.fields.append((name, chosen if chosen is not None else first or ""))
            self._select = None
        elif tag == "textarea" and self._textarea is not None:
            self.fields.append((self._textarea[0], self._textarea[1].removeprefix("\n")))
            self._textarea = None

    def handle_data(self, data: str) -> None:
        if self._textarea is not None:
            self._textarea[1] += data


def form_of(page: str, form_id: str, **values: object) -> list[tuple[str, str]]:
    """The form's fields as rendered, with ``values`` instead (a list: a repeated field)."""
    parser = FormFields(form_id)
    parser.feed(page)
    assert parser.fields, f"no form #{form_id} on the page"
    fields = [(k, v) for k, v in parser.fields if k not in values]
    for key, value in values.items():
        for one in value if isinstance(value, list) else [value]:
            fields.append((key, str(one)))
    return fields


class Browser:
    """A logged-in user's session with the web machine, over HTTP (redirects not followed)."""

    def __init__(self, url: str) -> None:
        self.url, self.session = url, requests.Session()

    def get(self, path: str) -> requests.Response:
        return self.session.get(self.url + path, allow_redirects=False, timeout=120)

    def post(self, path: str, data, files=None) -> requests.Response:
        token = self.session.cookies.get("csrftoken") or ""
        return self.session.post(self.url + path, data=data, files=files, timeout=300,
                                 headers={"X-CSRFToken": token}, allow_redirects=False)  # fmt: skip

    def log_in(self, username: str, password: str) -> None:
        assert self.get("/accounts/login/").status_code == 200  # the CSRF cookie
        answer = self.post("/accounts/login/", {"username": username, "password": password})
        assert answer.status_code == 302, answer.text[:2000]

    def poll(self, machines: Machines, path: str, what: str) -> dict:
        """GET ``path`` (JSON) until its ``status`` is done; returns the last answer."""

        def done() -> dict | None:
            answer = self.get(path)
            assert answer.status_code == 200, answer.text[:2000]
            body = answer.json()
            return body if body.get("status") == "done" else None

        return machines.wait(done, DEADLINE_S, what)

    def create_model(self, machines: Machines, name: str) -> int:
        """The Create model page: a small configuration on the uploaded track; the reward
        function is validated on a worker first (the page's pending poll), as in a browser."""
        page = self.get("/models/new/")
        assert page.status_code == 200 and f'value="{TRACK_ID}"' in page.text
        form = form_of(page.text, "create-form", name=name, track_id=TRACK_ID,
                       action_steering=[-30, 0, 30], action_speed=[1, 1, 1],
                       num_episodes_between_training=4, num_epochs=3, batch_size=32,
                       max_minutes=30, reward_function=CENTRE_LINE_REWARD)  # fmt: skip
        answer = self.post("/models/new/", form)
        if answer.status_code == 202:  # validating on a worker: poll, then post again
            poll = re.search(r'data-pending-poll="([^"]+)"', answer.text)
            result = self.poll(machines, html.unescape(poll[1]), "the reward validation")
            assert result["ok"], result
            answer = self.post("/models/new/", form)
        assert answer.status_code == 302, answer.text[-3000:]
        return int(re.fullmatch(r"/models/(\d+)/", answer.headers["Location"])[1])


def _job(model_id: int) -> TrainingJob | None:
    return TrainingJob.objects.filter(model_id=model_id).order_by("-pk").first()


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture
def machines(tmp_path: Path, s3_endpoint: str, redis_env: dict[str, str],
             settings) -> Iterator[Machines]:  # fmt: skip
    """The three machines' folders; their processes are stopped at the end."""
    minio = {"MINIO_ENDPOINT": s3_endpoint, "MINIO_ACCESS_KEY": S3_ACCESS_KEY,
             "MINIO_SECRET_KEY": S3_SECRET_KEY, "MINIO_BUCKET": "deepracer-e2e"}  # fmt: skip
    for name, value in minio.items():
        setattr(settings, name, value)  # this process reads the same store
    env = {k: v for k, v in os.environ.items() if k != "STORE_DIR"}
    env.update(redis_env, **minio, DATABASE_URL=database_url(),
               DJANGO_SETTINGS_MODULE="console.settings", DEBUG="1",
               SECRET_KEY=f"e2e-{uuid.uuid4().hex}{uuid.uuid4().hex}")  # fmt: skip
    moto_log = logging.getLogger("werkzeug")  # a line per S3 request: not in failure reports
    level = moto_log.level
    moto_log.setLevel(logging.WARNING)
    try:
        with ExitStack() as stack:
            yield Machines(tmp_path, env, stack)
    finally:
        moto_log.setLevel(level)


def test_a_web_and_workers_that_share_no_disk(machines: Machines) -> None:
    m = machines
    web, url = m.web()
    general = m.worker("worker", "worker", "evaluation,interactive,default", concurrency=2)
    lockstep = m.worker("trainer", "worker", "training")
    sim = m.worker("sim", "sim", "simulation")
    m.wait_ready(web, general, lockstep, sim)
    m.check_hidden()

    get_user_model().objects.create_user("racer", password=PASSWORD)
    browser = Browser(url)
    browser.log_in("racer", PASSWORD)

    # ---- the Tracks page: preview, then import; the file lands in the web's folder and in
    # the database, nowhere else
    preview = browser.post("/tracks/import/", {"preview": "1"},
                           files={"file": ("e2e loop.npy", _loop_track())})  # fmt: skip
    assert preview.status_code == 200, preview.text[-3000:]
    kept = re.search(r'name="kept" value="([^"]+)"', preview.text)[1]
    answer = browser.post("/tracks/import/", {"kept": kept, "track_id": TRACK_ID,
                                              "name": "E2E loop", "import": "1"})  # fmt: skip
    assert answer.status_code == 302, answer.text[-3000:]
    assert answer.headers["Location"] == f"/tracks/#track-{TRACK_ID}"
    recorded = TrackFile.objects.get(track_id=TRACK_ID)
    assert _sha256(m.roots["web"] / "var" / "tracks" / f"{TRACK_ID}.npy") == recorded.sha256

    first = browser.create_model(m, "lockstep-car")  # its reward validated on the worker
    second = browser.create_model(m, "streamed-car")

    # ---- training: the lockstep trainer takes the first job; a streamed trainer, started once
    # the first is busy, the second, whose episodes come from the simulation machine
    assert browser.post(f"/models/{first}/train/", {}).status_code == 302
    m.wait(lambda: (j := _job(first)) and j.status != JobStatus.QUEUED, DEADLINE_S,
           "the lockstep trainer to claim the first job")  # fmt: skip
    streamed = m.worker("streamer", "worker", "training", RACECRAFT_SIMULATION="streams",
                        RACECRAFT_REMOTE_ROLLOUT_SLOTS="1")  # fmt: skip
    m.wait_ready(streamed)
    m.check_hidden()
    assert browser.post(f"/models/{second}/train/", {}).status_code == 302
    for model_id in (first, second):  # stopped after the first iteration, as a user would
        job = m.wait(lambda mid=model_id: (j := _job(mid)) and (j.iterations or not j.is_active)
                     and j, DEADLINE_S, f"model {model_id}'s first iteration")  # fmt: skip
        assert job.status == JobStatus.IN_PROGRESS, job.error
        assert browser.post(f"/jobs/training/{job.pk}/stop/", {}).status_code == 302
    for model_id, trainer in ((first, lockstep), (second, streamed)):
        job = m.wait(lambda mid=model_id: (j := _job(mid)) and not j.is_active and j,
                     DEADLINE_S, f"model {model_id}'s training to end")  # fmt: skip
        assert job.status == JobStatus.COMPLETED, job.error
        assert job.iterations >= 1 and job.worker.startswith(f"{trainer.node}@"), job.worker
    episodes = re.compile(r"simulate_episodes\[[^]]+\] received")
    assert episodes.search(sim.log_path.read_text()), "no episodes from the simulation machine"

    # ---- evaluation of the first model on the uploaded track, by the worker machine
    page = browser.get(f"/models/{first}/")
    assert page.status_code == 200
    form = form_of(page.text, "evaluate-form", track_id=TRACK_ID, laps=3)
    answer = browser.post(f"/models/{first}/evaluate/", form)
    assert answer.status_code == 302, answer.text[-3000:]
    evaluation = m.wait(lambda: (e := EvaluationJob.objects.filter(model_id=first).first())
                        and not e.is_active and e, DEADLINE_S, "the evaluation")  # fmt: skip
    assert evaluation.status == JobStatus.COMPLETED, evaluation.error
    assert browser.get(f"/evaluations/{evaluation.pk}/video.mp4").status_code == 200

    # ---- the car archive: built by a worker into the store, downloaded from the web
    answer = browser.get(f"/models/{first}/download/car/")
    if answer.status_code == 202:
        poll = re.search(r'data-background-poll="([^"]+)"', answer.text)[1]
        result = browser.poll(m, html.unescape(poll), "the car export")
        assert result["ok"], result
        answer = browser.get(f"/models/{first}/download/car/")
    assert answer.status_code == 200, answer.text[-3000:]
    car = answer.content
    with tarfile.open(fileobj=io.BytesIO(car), mode="r:gz") as tar:
        assert {"agent/model.pb", "model_metadata.json"} <= set(tar.getnames())
        assert tar.extractfile("agent/model.pb").read()
        assert json.load(tar.extractfile("model_metadata.json"))["action_space"]

    # ---- and imported back: the upload goes to a worker through the store
    archive = {"archive": ("physicalmodel-lockstep-car.tar.gz", car)}
    answer = browser.post("/models/import/", {"name": "reimported-car"}, files=archive)
    assert answer.status_code == 302, answer.text[-3000:]
    task = re.search(r"task=(\w+)", answer.headers["Location"])[1]
    result = browser.poll(m, f"/api/tasks/{task}", "the model import")
    assert result["ok"], result
    assert browser.get(result["next"]).status_code == 200

    # ---- analysis: the page, and a chart's data for each model (from the store)
    assert browser.get(f"/models/{first}/analysis/").status_code == 200
    for model_id in (first, second):
        chart = browser.get(f"/models/{model_id}/analysis/data/progress.json")
        assert chart.status_code == 200, chart.text[:2000]
        assert len(chart.json()["iteration"]) >= 1 and chart.json()["episodes"][0] == 4
    chart = browser.get(f"/models/{first}/analysis/data/evaluations.json")
    assert chart.status_code == 200 and chart.json()["evaluations"][0]["laps"], chart.text[:2000]

    # ---- what each machine holds: the track, by its content, from the database; models and
    # logs only in the store
    m.check_hidden()
    for model_id in (first, second):
        assert get_store().exists(keys_for(model_id).best)
    track_files = {f"var/tracks/{TRACK_ID}.{ext}" for ext in ("npy", "json", "sha256")}
    for machine, root in m.roots.items():
        held = {str(p.relative_to(root)) for p in root.rglob("*") if p.is_file()}
        assert {f for f in held if not f.startswith("tmp/")} == track_files, (machine, held)
        assert _sha256(root / "var" / "tracks" / f"{TRACK_ID}.npy") == recorded.sha256
        assert (root / "var" / "tracks" / f"{TRACK_ID}.sha256").read_text() == recorded.sha256
