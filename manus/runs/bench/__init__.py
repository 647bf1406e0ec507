"""Benchmarks for `manus bench NAME`: one module each (see runs/cmd_bench.py)."""

import time


def best_time(fn, repeats: int) -> float:
    """The best wall time of `repeats` calls of `fn` [s] (warm it up first)."""
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best
