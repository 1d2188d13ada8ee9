"""What the import's integrity checks cost (issue 47): the masked CRC-32C of a TensorFlow
checkpoint's tensors and the NaN/infinity check of the weights.

Measures, on this machine, over random float32 bytes: google-crc32c's C implementation (what
:mod:`training.interchange.integrity` uses where it is installed, as on every supported
platform), its pure-Python fallback (table-driven, what the package falls back to where its C
extension cannot load) and :func:`~training.interchange.integrity.crc32c_numpy` (what the
import uses then instead), the numpy finiteness check, and the DeepRacer 3-layer network's
checkpoint (the one DeepRacer-on-AWS models hold: 5.8 million weights in its dense layer)
read into a policy (CRC and finiteness checks included), beside the CRC of all its tensors
and the finiteness check of all of them alone.

    .venv/bin/python bench/bench_import_integrity.py [--mb 4] [--repeats 3]

Last line: ``crc_c_mb_s=… crc_python_mb_s=… crc_numpy_mb_s=… finite_mb_s=… checkpoint_s=…
checkpoint_crc_ms=… checkpoint_finite_ms=…``.
Times are the best of ``--repeats`` (the machine may be shared).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import google_crc32c  # noqa: E402
import google_crc32c.python as crc_python  # noqa: E402
import numpy as np  # noqa: E402

from training.interchange import tfcheckpoint  # noqa: E402
from training.interchange.checkpointimport import policy_from_checkpoint  # noqa: E402
from training.interchange.coachexport import coach_variables  # noqa: E402
from training.interchange.integrity import crc32c_numpy, non_finite  # noqa: E402
from training.interchange.tfcheckpoint import read_checkpoint, write_checkpoint  # noqa: E402
from training.rl.checkpoints import new_model  # noqa: E402
from training.rl.metadata import build_metadata  # noqa: E402
from training.rl.policies import AWS_SHALLOW  # noqa: E402

MB = 1024 * 1024


def best(repeats: int, run: Callable[[], object]) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mb", type=float, default=4.0, help="bytes for the CRC rates, MB")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    data = np.random.default_rng(0).normal(size=int(args.mb * MB) // 4).astype("<f4")
    raw = data.tobytes()
    mb = len(raw) / MB
    print(f"google-crc32c implementation: {google_crc32c.implementation}")
    crc_c = best(args.repeats, lambda: google_crc32c.value(raw))
    crc_py = best(1, lambda: crc_python.value(raw))  # seconds per MB: once is enough
    crc_np = best(args.repeats, lambda: crc32c_numpy(raw))
    finite = best(args.repeats, lambda: non_finite(data))
    assert google_crc32c.value(raw) == crc_python.value(raw) == crc32c_numpy(raw)
    print(
        f"CRC-32C over {mb:.1f} MB: C {crc_c * 1000:.2f} ms, pure Python {crc_py:.2f} s, "
        f"numpy {crc_np * 1000:.0f} ms"
    )
    print(f"finiteness check over {mb:.1f} MB: {finite * 1000:.2f} ms")

    actions = [{"steering_angle": a, "speed": 1.0} for a in (-20, 0, 20)]
    metadata = build_metadata(action_space=actions, neural_network=AWS_SHALLOW)
    index, shard = write_checkpoint(coach_variables(new_model(metadata), metadata))
    print(f"{AWS_SHALLOW} checkpoint: {len(shard) / MB:.1f} MB of tensors")

    def import_it() -> None:
        policy_from_checkpoint(read_checkpoint(index, {0: shard}), metadata)

    checked = best(args.repeats, import_it)
    crc_all = best(args.repeats, lambda: tfcheckpoint.masked_crc32c(shard))
    finite_all = best(
        args.repeats, lambda: [non_finite(a) for a in read_checkpoint(index, {0: shard}).values()]
    )
    print(
        f"checkpoint → policy: {checked:.2f} s; the CRC of all its tensors {crc_all * 1000:.1f} "
        f"ms, reading them all and checking they are finite {finite_all * 1000:.1f} ms"
    )
    print(
        f"crc_c_mb_s={mb / crc_c:.0f} crc_python_mb_s={mb / crc_py:.2f} "
        f"crc_numpy_mb_s={mb / crc_np:.0f} "
        f"finite_mb_s={mb / finite:.0f} checkpoint_s={checked:.2f} "
        f"checkpoint_crc_ms={crc_all * 1000:.1f} checkpoint_finite_ms={finite_all * 1000:.1f}"
    )


if __name__ == "__main__":
    main()
