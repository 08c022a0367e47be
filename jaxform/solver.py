"""Newton's method with backtracking line search for one load step, inside jit.

Thesis Fig. 5.2, made robust: each iteration solves J dx = -R, then backtracks
(alpha = 1, 1/2, 1/4, ...) until ||R(x + alpha dx)|| <= (1 - 1e-4 alpha) ||R(x)|| and
the trial state is valid.  Convergence: ||R|| <= rtol * F, where F is the force scale of
the step (the largest of the root-sum-square of the element force vectors, the norm of
the contact forces and that of the external loads), so the test is relative to the forces
actually carried.

Failures are status codes (see jaxform.formulations): the caller cuts the step back.

:func:`solve_implicit` is the same Newton solve, differentiated by the implicit function
theorem instead of through its iterations: at the converged x*, R(x*, a) = 0 gives
dx*/da = -J^-1 dR/da, so a reverse pass needs one solve with the transposed Jacobian
of the converged step (y = J^-T xbar) and one VJP of the residual with respect to the
arguments (abar = -y^T dR/da).  The solve's auxiliary output (the new Gauss state,
aux = G(x*, a)) is differentiated too: xbar gains (dG/dx)^T auxbar before the solve and
abar gains (dG/da)^T auxbar.  Per step the reverse pass costs one Jacobian assembly
(forward mode over the element dofs, whose tangents also give (dG/dx)^T auxbar), one
transposed solve, and one linearization of (R, G) in the arguments transposed once with
the cotangent (-y, auxbar).  Where R is only piecewise smooth (contact and friction
switch between branches at an active-set change), the derivative is that of the branch
active at x*: exact away from a switch, one-sided at it.

Each call site of ``residual`` is compiled separately (~1-2 s of XLA time each on 2 cores),
so the start (x0, else the fallback) and the line search each evaluate it from one site
inside a while loop.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

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
    if x_fallback is None:
        r0, aux0, code0, scale0 = residual(x0)
    else:  # x0, then x_fallback if x0 is invalid, through one call site of the residual
        blank = jax.tree_util.tree_map(lambda a: jnp.zeros(a.shape, a.dtype),
                                       jax.eval_shape(residual, x0))

        def start_cond(c):
            k, _, out = c
            return (k == 0) | ((k == 1) & (out[2] != OK))

        def start_body(c):
            k = c[0]
            xk = jnp.where(k == 0, x0, x_fallback)
            return k + 1, xk, tuple(residual(xk))

        _, x0, (r0, aux0, code0, scale0) = jax.lax.while_loop(
            start_cond, start_body, (jnp.asarray(0), x0, tuple(blank)))
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

        if s.line_search:  # alpha = 1, 1/2, 1/4, ... while the decrease is insufficient
            def ls_cond(lc):
                return ~lc[2]

            def ls_body(lc):
                k, alpha = lc[0], lc[1]
                xt, rt, auxt, codet, scalet = trial(alpha)
                bad = (codet != OK) | (jnp.linalg.norm(rt) > (1.0 - 1e-4 * alpha) * rnorm)
                done = ~(bad & (k < s.max_backtracks))  # k backtracks done before this trial
                return (k + 1, 0.5 * alpha, done, xt, rt, auxt, codet, scalet)

            lc0 = (jnp.asarray(0), jnp.asarray(1.0, x.dtype), jnp.asarray(False),
                   x, r, aux, code_j, scale)
            _, _, _, xt, rt, auxt, codet, scalet = jax.lax.while_loop(ls_cond, ls_body, lc0)
        else:  # full steps: the backtracking loop is not compiled at all
            xt, rt, auxt, codet, scalet = trial(jnp.asarray(1.0, x.dtype))
        rtn = jnp.linalg.norm(rt)
        conv = (codet == OK) & (rtn <= s.rtol * scalet)
        hist = hist.at[it + 1].set(rtn / scalet)
        code = jnp.where(jnp.isfinite(dx).all(), codet, jnp.maximum(codet, 4))
        return xt, auxt, it + 1, code, rtn, conv, hist

    init = (x0, aux0, jnp.asarray(0), code0, n0, conv0, hist0)
    x, aux, it, code, rn, conv, hist = jax.lax.while_loop(cond, body, init)
    code = jnp.where(conv, OK, jnp.where(code == OK, NEWTON_NOT_CONVERGED, code))
    return x, aux, it, code, hist


@partial(jax.custom_vjp, nondiff_argnums=(0, 1, 2, 3, 4))
def solve_implicit(fn, fn_jac, fn_adj, linear, settings: NewtonSettings, x0, x_fallback, args):
    """Newton from x0 (x_fallback if x0 is invalid) on fn(., args) = 0, differentiable in
    ``args`` by the implicit function theorem (x0 and x_fallback get no derivative).

    fn(x, args) -> (R, aux, code, scale); fn_jac(x, args) -> (R, vals, aux, code, scale);
    fn_adj(x, args, aux_bar) -> (vals, (daux/dx)^T aux_bar), for the reverse pass;
    linear(vals, b, args, transpose) -> solution of J y = b (or J^T y = b).  Returns
    (x, aux, iterations, code, history) like :func:`newton`.  The functions must be
    hashable and close over no traced value: everything traced goes through ``args``.
    """
    return newton(lambda x: fn(x, args), lambda x: fn_jac(x, args),
                  lambda vals, b: linear(vals, b, args, False), x0, settings,
                  x_fallback=x_fallback)


def _solve_implicit_fwd(fn, fn_jac, fn_adj, linear, settings, x0, x_fallback, args):
    out = solve_implicit(fn, fn_jac, fn_adj, linear, settings, x0, x_fallback, args)
    return out, (out[0], args)


def _solve_implicit_bwd(fn, fn_jac, fn_adj, linear, settings, res, cot):
    """xbar_total = xbar + (dG/dx)^T auxbar;  J^T y = xbar_total;
    abar = (dG/da)^T auxbar - (dR/da)^T y.

    The x-derivatives come from forward mode (fn_adj: the Jacobian assembly, whose
    tangents carry dG/dx too), so the reverse pass through the residual is taken with
    respect to ``args`` only, and once, with the cotangent (-y, auxbar): one
    linearization and one transposition instead of a linearization in (x, args) and two
    transpositions (measured on the seed scene: see experiments/bench_gradient.py)."""
    x, args = res
    x_bar, aux_bar = cot[0], cot[1]
    vals, xg_bar = fn_adj(x, args, aux_bar)
    y = linear(vals, x_bar + xg_bar, args, True)

    def r_and_aux(a):
        r, aux, _, _ = fn(x, a)
        return r, aux

    _, vjp = jax.vjp(r_and_aux, args)
    (a_bar,) = vjp((-y, aux_bar))
    return jnp.zeros_like(x), jnp.zeros_like(x), a_bar


solve_implicit.defvjp(_solve_implicit_fwd, _solve_implicit_bwd)
