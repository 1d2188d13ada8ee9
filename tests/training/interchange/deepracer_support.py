"""DeepRacer's own models for the import tests.

- :func:`deepracer_style_graph` builds, with TensorFlow and independently of Racecraft's
  exporter, a frozen graph laid out as DeepRacer's SimApp writes it (its tensor names, the
  ``/255`` and ``-0`` input scaling, ``Conv2d_<n>/kernel`` + ``/read`` Identity nodes, a
  Shape/StridedSlice/Pack flatten, the ``middleware_fc_embedder`` dense layer, the gradient
  rescaler plumbing, and the head), from random weights.
- :func:`aws_samples` gives the real AWS-trained 3-layer-CNN models and camera frames shipped in
  the deepracer-utils source distribution, downloaded once with pip into ``var/cache`` (never
  committed); tests using it skip with the reason when PyPI cannot be reached.
"""

from __future__ import annotations

import subprocess
import sys
import tarfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

DEEPRACER_UTILS = "deepracer-utils==1.5.6"
CACHE = Path(__file__).resolve().parents[3] / "var" / "cache" / "deepracer-utils-1.5.6"
SAMPLE = "tests/deepracer/model/sample-model"
SHALLOW_CONVS = [(32, 8, 4), (64, 4, 2), (64, 3, 1)]


def deepracer_style_graph(
    sensor: str, kind: str, n_actions: int, seed: int, convs=SHALLOW_CONVS
) -> bytes:
    """A frozen DeepRacer-style policy graph as bytes. ``kind``: ``ppo_discrete`` (softmax),
    ``ppo_continuous`` (the raw means, -1..1 of the ranges) or ``sac`` (tanh of the means)."""
    tf = pytest.importorskip("tensorflow", reason="TensorFlow is in the [tf] test extra")
    v1 = tf.compat.v1
    rng = np.random.default_rng(seed)
    channels = 2 if sensor == "STEREO_CAMERAS" else 1
    head = "policy" if kind == "sac" else "main"
    net = "network_0" if kind == "sac" else "network_1"
    scope = f"main_level/agent/{head}/online/{net}"

    def weight(name: str, shape: tuple[int, ...], fan_in: int):
        value = rng.normal(0, 1.5 / fan_in**0.5, shape).astype(np.float32)
        return tf.identity(tf.constant(value, name=name), name=f"{name}/read")

    graph = tf.Graph()
    with graph.as_default():
        x = v1.placeholder(
            tf.float32, [None, 120, 160, channels],
            name=f"main_level/agent/{head}/online/network_0/{sensor}/{sensor}",
        )  # fmt: skip
        with tf.name_scope(f"{scope}/{sensor}/"):
            x = tf.subtract(tf.divide(x, 255.0, name="truediv"), 0.0, name="sub")
            for i, (filters, kernel, stride) in enumerate(convs):
                fan_in = kernel * kernel * x.shape[-1]
                k = weight(f"Conv2d_{2 * i}/kernel", (kernel, kernel, x.shape[-1], filters), fan_in)
                b = weight(f"Conv2d_{2 * i}/bias", (filters,), 10)
                x = tf.nn.conv2d(
                    x, k, [1, stride, stride, 1], "VALID", name=f"Conv2d_{2 * i}/Conv2D"
                )
                x = tf.nn.relu(tf.nn.bias_add(x, b), name=f"BatchnormActivationDropout_{2 * i + 1}")
            flat = int(np.prod(x.shape[1:]))
            x = tf.reshape(x, tf.stack([tf.shape(x)[0], flat]), name="Flatten/flatten/Reshape")
        with tf.name_scope(f"{scope}/middleware_fc_embedder/"):
            x = tf.matmul(x, weight("Dense_0/kernel", (flat, 512), flat), name="Dense_0/MatMul")
            x = tf.nn.relu(tf.nn.bias_add(x, weight("Dense_0/bias", (512,), 10)))
        with tf.name_scope(f"{scope}/"):
            rescale = tf.identity(tf.constant(1.0, name="rescaler"), name="rescaler/read")
            packed = tf.stack([x])
            x = tf.add((1.0 - rescale) * tf.stop_gradient(packed), rescale * packed)[0]
        name = "sac_policy_head_0" if kind == "sac" else "ppo_head_0"
        with tf.name_scope(f"{scope}/{name}/"):
            x = tf.matmul(x, weight("policy_fc/kernel", (512, n_actions), 512))
            x = tf.nn.bias_add(x, weight("policy_fc/bias", (n_actions,), 10))
            final = {"sac": tf.tanh, "ppo_discrete": tf.nn.softmax}.get(kind, tf.identity)
            final(x, name="policy")
    return graph.as_graph_def().SerializeToString()


@dataclass(frozen=True)
class AwsSamples:
    """Three checkpoints of one AWS-trained model and the frames DeepRacer's tests use."""

    graphs: dict[int, bytes]  # iteration → model_<iteration>.pb
    metadata: bytes
    frames: np.ndarray  # (3, 120, 160, 1) float32 0..255


def _download() -> Path:
    marker = CACHE / "done"
    if marker.exists():
        return CACHE
    CACHE.mkdir(parents=True, exist_ok=True)
    result = subprocess.run(
        [sys.executable, "-m", "pip", "download", "--no-deps", "--no-binary", ":all:",
         "-q", "-d", str(CACHE), DEEPRACER_UTILS],
        capture_output=True, timeout=600, check=False,
    )  # fmt: skip
    sdists = sorted(CACHE.glob("deepracer_utils-*.tar.gz"))
    if result.returncode or not sdists:
        pytest.skip(f"cannot download the {DEEPRACER_UTILS} sdist: {result.stderr[-300:]!r}")
    with tarfile.open(sdists[0]) as tar:
        for member in tar.getmembers():
            if f"/{SAMPLE}/" in member.name and member.isfile():
                target = CACHE / member.name.split(f"/{SAMPLE}/", 1)[1]
                target.parent.mkdir(parents=True, exist_ok=True)
                target.write_bytes(tar.extractfile(member).read())
    sdists[0].unlink()
    marker.write_text("ok\n")
    return CACHE


def aws_samples() -> AwsSamples:
    """The deepracer-utils sample model (skips the test when it cannot be had)."""
    import cv2

    root = _download()
    graphs = {int(p.stem.split("_")[1]): p.read_bytes() for p in root.glob("model/model_*.pb")}
    frames = []
    for picture in sorted(root.glob("pictures/*.png")):
        image = cv2.resize(cv2.imread(str(picture)), (160, 120), interpolation=cv2.INTER_CUBIC)
        frames.append(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)[..., None])
    metadata = (root / "model" / "model_metadata.json").read_bytes()
    return AwsSamples(graphs, metadata, np.stack(frames).astype(np.float32))


def checkpoint_of(graph: bytes, name: str = "model/12_Step-3400.ckpt") -> dict[str, bytes]:
    """A TensorFlow (TF1 Saver, TensorBundle) checkpoint holding the weights of a frozen
    DeepRacer-style graph as variables of the same names, plus what DeepRacer's checkpoints
    also hold: Adam slots, a target network copy, a value head and the global step."""
    import tempfile
    from pathlib import Path

    tf = pytest.importorskip("tensorflow", reason="TensorFlow is in the [tf] test extra")
    v1 = tf.compat.v1
    graph_def = v1.GraphDef()
    graph_def.ParseFromString(graph)
    weights = {
        n.name: tf.make_ndarray(n.attr["value"].tensor)
        for n in graph_def.node
        if n.op == "Const" and n.name.endswith(("/kernel", "/bias"))
    }
    extra = {f"{k}/Adam": v + 1 for k, v in weights.items()}
    extra |= {k.replace("/online/", "/target/"): v - 1 for k, v in weights.items()}
    extra["main_level/agent/main/online/network_0/v_values_head_0/output/kernel"] = np.ones(
        (512, 1), np.float32
    )
    with tf.Graph().as_default(), v1.Session() as session:
        for key, value in (weights | extra).items():
            v1.get_variable(key, initializer=value)
        v1.train.get_or_create_global_step()
        session.run(v1.global_variables_initializer())
        with tempfile.TemporaryDirectory() as folder:
            v1.train.Saver().save(session, f"{folder}/ckpt", write_meta_graph=False)
            return {
                f"{name}{p.name.removeprefix('ckpt')}": p.read_bytes()
                for p in Path(folder).glob("ckpt.*")
            }
