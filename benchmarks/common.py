"""Shared helpers of the benchmark scripts."""

from __future__ import annotations

import time


def wall_times(fn, repeat: int = 5, warm: int = 0) -> list[float]:
    """Wall times of `repeat` calls of fn() after `warm` untimed calls, seconds."""
    for _ in range(warm):
        fn()
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return times


def best_of(fn, repeat: int = 5) -> float:
    """Best wall time of `repeat` calls of fn(), seconds."""
    return min(wall_times(fn, repeat))
