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


def interleaved(fns, repeats: int, release=None, warm_up: bool = True) -> list[float]:
    """Best wall time (s) of each of ``fns`` (after one warm-up call each, unless the
    caller made it: ``warm_up=False``), the calls made in turn ``repeats`` times: a
    machine whose speed drifts (a shared host) slows all of them alike, so their ratios
    hold better than with one best-of after another.  ``release``: {index: function}
    called untimed on that call's result (e.g. to free a sparse factorization)."""
    import jax

    release = release or {}
    for i, fn in enumerate(fns if warm_up else ()):
        out = jax.block_until_ready(fn())
        if i in release:
            jax.block_until_ready(release[i](out))
    best = [np.inf] * len(fns)
    for _ in range(repeats):
        for i, fn in enumerate(fns):
            t0 = time.perf_counter()
            out = jax.block_until_ready(fn())
            best[i] = min(best[i], time.perf_counter() - t0)
            if i in release:
                jax.block_until_ready(release[i](out))
    return best


def cold_and_warm(cfg: dict):
    """(scene, result, first run's wall time incl. compilation, second run's) of the
    scene of a validated config; the second run reuses the first's compiled program."""
    from jaxform.scenes import build_scene
    from jaxform.simulation import simulate

    t0 = time.perf_counter()
    scene = build_scene(cfg)
    simulate(scene)
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    res = simulate(build_scene(cfg))
    return scene, res, first, time.perf_counter() - t0
