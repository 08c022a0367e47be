"""Timing helper shared by the benchmark scripts (imported from their own folder)."""

from __future__ import annotations

import time

import numpy as np


def best_of(fn, repeats: int) -> float:
    """Best wall time (s) of ``repeats`` calls of ``fn`` after one warm-up call, each call
    waited for (``jax.block_until_ready``: JAX dispatches asynchronously)."""
    import jax

    jax.block_until_ready(fn())
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        best = min(best, time.perf_counter() - t0)
    return best


def cold_and_warm(cfg: dict):
    """(scene, result, first run's wall time incl. compilation, second run's) of the
    scene of a validated config; the second run reuses the first's compiled program."""
    from jaxform.scenes import build_scene
    from jaxform.simulate import simulate

    t0 = time.perf_counter()
    scene = build_scene(cfg)
    simulate(scene)
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    res = simulate(build_scene(cfg))
    return scene, res, first, time.perf_counter() - t0
