"""A Newton solve that stalls stops early and its step is cut back (issue 41).

On the closed die with flash (configs/closed_die_flash.toml) a third of the Newton
iterations were spent in attempts that crawled for all 25 iterations (the residual down by
a few per cent each, the line search cutting most of every step) before the step was
halved anyway.  References: the stall test on given residual histories (by hand), a
residual with no root (Newton stalls at its least norm, 1), and the config keys.  The
scene-level effect is measured by experiments/newton_profile.py (docs/benchmarks.md).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_upsetting import scene

from jaxform.solver import NewtonSettings, newton, stalled
from jaxform.status import NEWTON_NOT_CONVERGED, OK

ON = NewtonSettings(stall_iterations=4, stall_ratio=0.9)


def test_stall_test_on_given_histories():
    """Stalled: the least ||R|| / F so far above 0.9 x the least of 4 iterations before."""
    inf = np.inf
    crawl = jnp.asarray([1.0, 0.95, 0.93, 0.92, 0.91, inf, inf])
    fall = jnp.asarray([1.0, 0.95, 0.93, 0.92, 0.89, inf, inf])
    bump = jnp.asarray([0.5, 2.0, 3.0, 1.0, 0.6, 0.44, inf])  # the least so far counts
    yes = jnp.asarray(True)
    assert bool(stalled(crawl, 4, ON, yes))
    assert not bool(stalled(crawl, 3, ON, yes))  # fewer than 4 iterations: never
    assert not bool(stalled(crawl, 4, ON, jnp.asarray(False)))  # the caller cannot cut
    assert not bool(stalled(crawl, 4, NewtonSettings(), yes))  # off by default
    assert not bool(stalled(crawl, 4, ON, None))
    assert not bool(stalled(fall, 4, ON, yes))
    assert bool(stalled(bump, 4, ON, yes))  # 0.5 before, 0.5 still the least
    assert not bool(stalled(bump, 5, ON, yes))  # 0.44 < 0.9 x 0.5


def _no_root(x):  # R(x) = x^2 + 1: no real root; Newton with line search creeps to x = 0
    r = x**2 + 1.0
    return r, jnp.sum(x), jnp.asarray(OK), jnp.asarray(1.0)


def _no_root_jacobian(x, aux):
    return (2.0 * x).ravel()


def _solve(x0, settings, give_up):
    return jax.jit(
        lambda x: newton(
            _no_root, _no_root_jacobian, lambda v, b: b / v, x, settings, give_up=give_up
        )
    )(x0)


def test_a_solve_with_no_root_stops_once_it_stalls():
    """From x = 3 the line search brings ||R|| to ~1 within a few iterations and then
    cannot lower it: with the rule the solve stops 4 iterations after its least residual
    stopped falling by 10 %, not converged; without it (or where the caller cannot cut
    the step) it takes all 25."""
    x0 = jnp.asarray([3.0])
    settings = NewtonSettings(max_iterations=25, stall_iterations=4)
    _, _, its_off, code_off, _, _ = _solve(x0, NewtonSettings(max_iterations=25), None)
    _, _, its_no, code_no, _, _ = _solve(x0, settings, jnp.asarray(False))
    _, _, its, code, hist, _ = _solve(x0, settings, jnp.asarray(True))
    assert int(its_off) == int(its_no) == 25
    assert int(code) == int(code_off) == int(code_no) == NEWTON_NOT_CONVERGED
    assert 4 <= int(its) < 12
    h = np.asarray(hist)[: int(its) + 1]
    assert h.min() >= 1.0 and h[: int(its) - 3].min() <= h.min() / 0.9


def test_the_stall_settings_reach_the_solver_from_the_config():
    """solver.stall_iterations / stall_ratio become the scene's Newton settings (off by
    default); a ratio outside (0, 1) is refused by name before anything compiles."""
    from jaxform.config import ConfigError

    assert scene().newton.stall_iterations == 0
    on = scene("solver.stall_iterations=8", "solver.stall_ratio=0.8").newton
    assert (on.stall_iterations, on.stall_ratio) == (8, 0.8)
    with pytest.raises(ConfigError, match="solver.stall_ratio"):
        scene("solver.stall_ratio=1.5")
