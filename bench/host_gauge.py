"""The host gauge the benchmarks print: a fixed pure-Python loop timed in the same run.

This host is a shared VM whose speed swings ~2x between moments and days on the same tree, so a benchmark's factors
from different runs are compared only after their gauges are.
"""
from __future__ import annotations

import math
import time


def host_gauge(repeats: int = 5) -> float:
    """Best time [ms] of a fixed pure-Python loop (10^6 iterations, the interpreter work the Python stages do between
    compiled calls), a reading of the host's speed."""
    best = math.inf
    for _ in range(repeats):
        start = time.perf_counter()
        total = 0
        for i in range(1_000_000):
            total += i & 7
        best = min(best, time.perf_counter() - start)
    return best * 1e3


def gauge_line() -> str:
    """The gauge as the benchmarks print it."""
    return f"Host gauge (10^6 Python loop iterations, best of 5): {host_gauge():.1f} ms"
