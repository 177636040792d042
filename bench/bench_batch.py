"""Scaling of ``needle_batch sweep`` on a LocalCluster: 1, 2 and 4 worker processes on 24 tasks (the 3 sample bags x
8 values of damping.rayleigh_beta, each bag cut to --duration seconds), issue 17 benchmark.

Per worker count: wall time of the 24 tasks (workers started and warmed up beforehand: one task each, not counted),
tasks per minute, efficiency = wall(1 worker) / (N x wall(N workers)), the mean compute time of a task (its own wall
time on the worker) and the scheduling overhead per task (N x wall - sum of task times) / tasks. A second table: the
round trip of trivial tasks through the scheduler (submit to result), the pure per-task overhead of Dask.

Run from the repository root with the installed environment (the sample experiments name their calibration files
relative to it):  source .venv/needle_env.sh && python bench/bench_batch.py [--duration 1.0] [--workers 1 2 4]
"""
from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

from needle_sim_ros.batch.bags import resolve_bags
from needle_sim_ros.batch.cluster import map_ordered, open_client
from needle_sim_ros.batch.sweep import plan
from needle_sim_ros.batch.task import run_row

BETAS = [1.0e-4 * (1 + k / 4) for k in range(8)]
TRIVIAL_TASKS = 200


def trivial(k: int) -> int:
    return k


def measure(workers: int, duration: float) -> dict[str, float]:
    entries = resolve_bags("bags")
    sets = [{"needle_simulator": {"damping.rayleigh_beta": beta}} for beta in BETAS]
    with open_client(workers) as client:
        tasks = plan(client, entries, sets, None, duration)
        client.run(run_row, tasks[len(BETAS)])  # warm-up on every worker (imports, compiled-code caches)
        start = time.perf_counter()
        rows = map_ordered(client, run_row, tasks, quiet=True)
        wall = time.perf_counter() - start
        start = time.perf_counter()
        map_ordered(client, trivial, list(range(TRIVIAL_TASKS)), quiet=True)
        trivial_s = (time.perf_counter() - start) / TRIVIAL_TASKS
    failed = [r for r in rows if r["status"] != "ok"]
    if failed:
        raise SystemExit(f"bench_batch: {len(failed)} task(s) failed: {failed[0]['error']}")
    compute = [r["wall_s"] for r in rows]
    return {"workers": workers, "tasks": len(rows), "wall_s": wall, "tasks_per_min": 60 * len(rows) / wall,
            "task_mean_s": statistics.mean(compute), "task_median_s": statistics.median(compute),
            "overhead_s": (workers * wall - sum(compute)) / len(rows), "trivial_s": trivial_s}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=1.0, help="seconds of each bag (default 1.0)")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2, 4])
    args = parser.parse_args()
    if not Path("bags").is_dir():
        raise SystemExit("bench_batch: run from the repository root (bags/ not found)")
    results = [measure(n, args.duration) for n in args.workers]
    base = results[0]["wall_s"] * results[0]["workers"]
    print(f"\n24 tasks = 3 sample bags x 8 parameter sets, {args.duration:g} s of each bag\n")
    print("| workers | wall [s] | tasks/min | efficiency | task compute mean / median [s] | overhead/task [s] |")
    print("|---|---|---|---|---|---|")
    for r in results:
        print(f"| {r['workers']} | {r['wall_s']:.1f} | {r['tasks_per_min']:.1f} | "
              f"{base / (r['workers'] * r['wall_s']):.2f} | {r['task_mean_s']:.2f} / {r['task_median_s']:.2f} | "
              f"{r['overhead_s']:.3f} |")
    print(f"\nscheduler round trip of a trivial task ({TRIVIAL_TASKS} tasks): "
          + ", ".join(f"{r['workers']} worker(s) {r['trivial_s'] * 1e3:.1f} ms" for r in results))


if __name__ == "__main__":
    main()
