"""Shared timing helper for the benchmark scripts (run them as `python benchmarks/<script>.py`,
which puts this folder on the import path)."""

from __future__ import annotations

import statistics
import time


def median_us(function, count: int, repeats: int = 7) -> float:
    """Median over `repeats` batches of the mean cost of one call of `function`, microseconds."""
    samples = []
    for _ in range(repeats):
        started = time.perf_counter()
        for _ in range(count):
            function()
        samples.append((time.perf_counter() - started) / count * 1e6)
    return statistics.median(samples)
