"""Per-call cost of the reward function: plain in-process vs the sandboxed paths.

    .venv/bin/python bench/bench_sandbox.py [--calls 200000] [--track racecraft_oval]

Measured in one run on the same params (built by the simulator for a mid-lap car):
- inprocess: the user's function called directly in this process (no guard, no copy);
- sandboxed: the guarded call inside the locked-down child, as the rollout loop makes it
  (heartbeat, params copy, result check);
- raw_in_child: the bare function in the child (so the guard's own cost is visible);
- ipc: one pipe round trip per call to a sandbox (SandboxedReward), for comparison.
The last line is key=value pairs; the step budget is 500 us (2,000 env steps/s).
"""

from __future__ import annotations

import argparse
import time

from racing.params import scenario_params
from racing.tracks import TrackCatalog
from training.rewards.examples import example_source
from training.sandbox import SandboxedReward, SandboxLimits, run_sandboxed
from training.sandbox.oneshot import TIMING_TARGET

STEP_BUDGET_US = 500.0


def plain_call_us(source: str, params: dict, calls: int) -> float:
    namespace: dict = {}
    exec(compile(source, "reward_function.py", "exec"), namespace)
    fn = namespace["reward_function"]
    best = float("inf")
    for _ in range(3):
        t0 = time.perf_counter_ns()
        for _ in range(calls):
            fn(params)
        best = min(best, (time.perf_counter_ns() - t0) / calls / 1000)
    return best


def sandboxed_call_us(source: str, params: dict, calls: int) -> tuple[float, float]:
    """Best of two timed runs in a sandbox (guarded, bare) after one run that is not counted."""

    def timed_run() -> dict:
        return run_sandboxed(
            target=TIMING_TARGET,
            reward_source=source,
            args={"params": params, "n": calls},
            limits=SandboxLimits(),
            timeout=600,
        )

    timed_run()  # warm-up, not counted
    runs = [timed_run() for _ in range(2)]
    return (
        min(run["guarded_ns"] for run in runs) / 1000,
        min(run["raw_ns"] for run in runs) / 1000,
    )


def ipc_call_us(source: str, params: dict, calls: int) -> float:
    with SandboxedReward(source) as reward:
        reward(params)
        t0 = time.perf_counter_ns()
        for _ in range(calls):
            reward(params)
        return (time.perf_counter_ns() - t0) / calls / 1000


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=200_000)
    parser.add_argument("--ipc-calls", type=int, default=2_000)
    parser.add_argument("--track", default="racecraft_oval")
    parser.add_argument("--example", default="follow_center_line")
    args = parser.parse_args()
    params = scenario_params(TrackCatalog().load(args.track), "mid_lap")
    source = example_source(args.example)

    inprocess = plain_call_us(source, params, args.calls)
    sandboxed, raw_child = sandboxed_call_us(source, params, args.calls)
    ipc = ipc_call_us(source, params, args.ipc_calls)
    overhead = sandboxed - inprocess
    rows = [
        ("in-process plain call", inprocess),
        ("sandboxed, in-child guarded call", sandboxed),
        ("sandboxed, in-child bare call", raw_child),
        ("one-shot IPC round trip per call", ipc),
    ]
    print(f"reward: {args.example}  track: {args.track}  waypoints: {len(params['waypoints'])}")
    print(f"{'path':40s} {'us/call':>10s} {'% of 500 us step':>18s}")
    for name, us in rows:
        print(f"{name:40s} {us:10.3f} {100 * us / STEP_BUDGET_US:17.2f}%")
    print(
        f"inprocess_us={inprocess:.3f} sandboxed_us={sandboxed:.3f} overhead_us={overhead:.3f} "
        f"ipc_us={ipc:.3f} step_budget_us={STEP_BUDGET_US:.0f} "
        f"overhead_pct_of_step={100 * overhead / STEP_BUDGET_US:.2f}"
    )


if __name__ == "__main__":
    main()
