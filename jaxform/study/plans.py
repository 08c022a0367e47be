"""Sampling plans on the unit hypercube and the inverse CDFs that map them to inputs.

* Latin hypercube: n samples; in each input the n strata [k/n, (k+1)/n) hold one sample
  each (a random point inside its stratum), the strata paired at random between inputs.
* Sobol: the first n points of a scrambled Sobol sequence (scipy.stats.qmc, Owen
  scrambling from the seed); n a power of 2, where every dyadic box of volume 1/n holds
  one point.
* Monte Carlo: n independent uniform points.
* Full factorial: every combination of given levels (no unit cube).

Inverse CDFs: uniform(low, high), normal(mean, std), lognormal(mu, sigma) (ln X normal with
mean mu and standard deviation sigma), levels(a, b, ...) (each level equally likely).
Imports no JAX.
"""

from __future__ import annotations

import itertools

import numpy as np
from scipy.special import ndtri
from scipy.stats import qmc


def latin_hypercube(n: int, d: int, seed: int) -> np.ndarray:
    """(n, d) points in [0, 1)^d, one in each of the n strata of every coordinate."""
    rng = np.random.default_rng(seed)
    strata = np.stack([rng.permutation(n) for _ in range(d)], axis=1)
    return (strata + rng.random((n, d))) / n


def sobol(n: int, d: int, seed: int) -> np.ndarray:
    """(n, d) first points of a scrambled Sobol sequence (n a power of 2)."""
    return qmc.Sobol(d, scramble=True, seed=seed).random_base2(int(np.log2(n)))


def monte_carlo(n: int, d: int, seed: int) -> np.ndarray:
    """(n, d) independent uniform points in [0, 1)^d."""
    return np.random.default_rng(seed).random((n, d))


UNIT_PLANS = {"latin_hypercube": latin_hypercube, "sobol": sobol, "monte_carlo": monte_carlo}


def unit_plan(plan: str, n: int, d: int, seed: int) -> np.ndarray:
    return UNIT_PLANS[plan](n, d, seed)


def full_factorial(levels: list[np.ndarray]) -> np.ndarray:
    """Every combination of the levels, (prod of counts, inputs); the last input varies
    fastest."""
    return np.array(list(itertools.product(*[list(map(float, v)) for v in levels])), dtype=float)


def inverse_cdf(dist: str, params: tuple[float, ...], u: np.ndarray) -> np.ndarray:
    """The values of a distribution at probabilities u in [0, 1) (u = 0 of a normal is
    moved to the smallest positive double: ndtri(0) is -inf)."""
    u = np.asarray(u, dtype=float)
    if dist == "uniform":
        low, high = params
        return low + (high - low) * u
    if dist == "levels":
        values = np.asarray(params, dtype=float)
        return values[np.minimum((u * len(values)).astype(int), len(values) - 1)]
    z = ndtri(np.clip(u, np.finfo(float).tiny, 1.0))
    mu, sigma = params
    if dist == "normal":
        return mu + sigma * z
    if dist == "lognormal":
        return np.exp(mu + sigma * z)
    raise ValueError(f"unknown distribution {dist!r}")
