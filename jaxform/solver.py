"""Newton's method with backtracking line search for one load step, inside jit.

Thesis Fig. 5.2, made robust: each iteration solves J dx = -R, then backtracks
(alpha = 1, 1/2, 1/4, ...) until ||R(x + alpha dx)|| <= (1 - 1e-4 alpha) ||R(x)|| and
the trial state is valid.  Convergence: ||R|| <= rtol * F, where F is the force scale of
the step (the larger of the root-sum-square of the element force vectors and the norm of
the contact forces), so the test is relative to the forces actually carried.

Failures are status codes (see jaxform.formulations): the caller cuts the step back.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp

from jaxform.formulations import NEWTON_NOT_CONVERGED, OK


@dataclass(frozen=True)
class NewtonSettings:
    max_iterations: int = 25
    rtol: float = 1e-10
    line_search: bool = True
    max_backtracks: int = 10


def newton(residual, residual_and_jacobian, linear_solve, x0, settings: NewtonSettings,
           x_fallback=None):
    """Solve R(x) = 0 from x0 (or from x_fallback if x0 is not a valid state, e.g. a
    predictor that inverts an element).

    residual(x) -> (R, aux, code, scale); residual_and_jacobian(x) -> (R, vals, aux, code,
    scale); linear_solve(vals, b) -> solution.  Returns (x, aux, iterations, code,
    history) with history[k] = ||R_k|| / scale_k (NaN-free; inf where not reached).
    """
    s = settings
    r0, aux0, code0, scale0 = residual(x0)
    if x_fallback is not None:
        x0, r0, aux0, code0, scale0 = jax.lax.cond(
            code0 == OK, lambda: (x0, r0, aux0, code0, scale0),
            lambda: (x_fallback,) + tuple(residual(x_fallback)))
    n0 = jnp.linalg.norm(r0)
    hist0 = jnp.full(s.max_iterations + 1, jnp.inf).at[0].set(n0 / scale0)
    conv0 = (code0 == OK) & (n0 <= s.rtol * scale0)

    def cond(c):
        x, aux, it, code, rn, conv, hist = c
        return (~conv) & (code == OK) & (it < s.max_iterations)

    def body(c):
        x, aux, it, code, rn, conv, hist = c
        r, vals, _, code_j, scale = residual_and_jacobian(x)
        dx = linear_solve(vals, -r)
        rnorm = jnp.linalg.norm(r)

        def trial(alpha):
            xt = x + alpha * dx
            rt, auxt, codet, scalet = residual(xt)
            return xt, rt, auxt, codet, scalet

        def ls_cond(lc):
            k, alpha, _, rt, _, codet, _ = lc
            bad = (codet != OK) | (jnp.linalg.norm(rt) > (1.0 - 1e-4 * alpha) * rnorm)
            return s.line_search & bad & (k < s.max_backtracks)

        def ls_body(lc):
            k, alpha, *_ = lc
            alpha = 0.5 * alpha
            return (k + 1, alpha) + trial(alpha)

        lc0 = (0, jnp.asarray(1.0, x.dtype)) + trial(jnp.asarray(1.0, x.dtype))
        if s.line_search:
            _, _, xt, rt, auxt, codet, scalet = jax.lax.while_loop(ls_cond, ls_body, lc0)
        else:  # not traced at all: the backtracking loop costs ~5 s of compile time
            _, _, xt, rt, auxt, codet, scalet = lc0
        rtn = jnp.linalg.norm(rt)
        conv = (codet == OK) & (rtn <= s.rtol * scalet)
        hist = hist.at[it + 1].set(rtn / scalet)
        code = jnp.where(jnp.isfinite(dx).all(), codet, jnp.maximum(codet, 4))
        return xt, auxt, it + 1, code, rtn, conv, hist

    init = (x0, aux0, jnp.asarray(0), code0, n0, conv0, hist0)
    x, aux, it, code, rn, conv, hist = jax.lax.while_loop(cond, body, init)
    code = jnp.where(conv, OK, jnp.where(code == OK, NEWTON_NOT_CONVERGED, code))
    return x, aux, it, code, hist
