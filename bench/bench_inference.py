"""Policy inference per camera frame on one core: the "ONNX policy" download in onnxruntime
against the car download (frozen TensorFlow graph) converted by OpenVINO as the car converts it.

Both run the same randomly initialised PPO policy (discrete, 10 actions) on 160×120 grayscale
frames, batch 1, one thread, after a warm-up; the networks are Racecraft's lean default and
DeepRacer's 3-layer CNN.

    .venv/bin/python bench/bench_inference.py [--frames N]

Last line: ``onnx_ms=… openvino_ms=… ratio=…`` for the lean network (goal: onnx_ms ≤ 2).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import onnxruntime as ort  # noqa: E402
import openvino as ov  # noqa: E402
import torch  # noqa: E402

from training.interchange.carmodel import export_car_graph, input_name  # noqa: E402
from training.interchange.export import export_onnx, new_model  # noqa: E402
from training.rl.metadata import build_metadata  # noqa: E402
from training.rl.policies import LEAN, SHALLOW  # noqa: E402

torch.set_num_threads(1)
ACTIONS = [{"steering_angle": a, "speed": s} for a in (-30, -10, 0, 10, 30) for s in (1.0, 2.5)]


def per_frame_ms(run, frames: np.ndarray) -> float:
    """Median of 5 passes over ``frames`` (milliseconds per frame), after 20 warm-up calls."""
    for frame in frames[:20]:
        run(frame)
    passes = []
    for _ in range(5):
        start = time.perf_counter()
        for frame in frames:
            run(frame)
        passes.append((time.perf_counter() - start) * 1000 / len(frames))
    return float(np.median(passes))


def onnx_runner(onnx_bytes: bytes):
    options = ort.SessionOptions()
    options.intra_op_num_threads = options.inter_op_num_threads = 1
    session = ort.InferenceSession(onnx_bytes, options, providers=["CPUExecutionProvider"])
    return lambda frame: session.run(None, {"observation": frame.transpose(2, 0, 1)[None]})


def openvino_runner(graph: bytes, name: str):
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "model.pb"
        path.write_bytes(graph)
        converted = ov.convert_model(str(path), input=[(f"{name}:0", [1, 120, 160, 1])])
    # f32 as on the car's Atom: OpenVINO would pick bfloat16 by itself where the CPU has it.
    config = {"INFERENCE_NUM_THREADS": 1, "NUM_STREAMS": 1, "INFERENCE_PRECISION_HINT": "f32"}
    request = ov.Core().compile_model(converted, "CPU", config).create_infer_request()
    return lambda frame: request.infer([frame[None]])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=300)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 256, (args.frames, 120, 160, 1)).astype(np.float32)
    print(f"{'network':<38} {'onnxruntime ms':>15} {'OpenVINO ms':>12} {'ratio':>7}")
    results = {}
    for network in (LEAN, SHALLOW):
        meta = build_metadata(action_space=ACTIONS, neural_network=network)
        model = new_model(meta)
        onnx_ms = per_frame_ms(onnx_runner(export_onnx(model, meta)), frames)
        graph = export_car_graph(model, meta)
        ov_ms = per_frame_ms(openvino_runner(graph, input_name("clipped_ppo", meta.camera)), frames)
        results[network] = (onnx_ms, ov_ms)
        print(f"{network:<38} {onnx_ms:>15.3f} {ov_ms:>12.3f} {onnx_ms / ov_ms:>7.2f}")
    onnx_ms, ov_ms = results[LEAN]
    print(f"onnx_ms={onnx_ms:.3f} openvino_ms={ov_ms:.3f} ratio={onnx_ms / ov_ms:.2f}")


if __name__ == "__main__":
    main()
