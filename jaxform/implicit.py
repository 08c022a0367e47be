"""Safeguarded scalar root finding, differentiated by the implicit function theorem.

`root_scalar(fn, args, lo, hi, x0)` finds x in [lo, hi] with fn(x, args) = 0 for an
fn that is *increasing across the bracket*: fn(lo) <= 0 <= fn(hi).  The iteration is
Newton with bisection as the safeguard (a Newton step that leaves the current bracket,
or a non-finite/non-positive slope, is replaced by bisection, and every evaluation
shrinks the bracket), so it cannot diverge and never produces NaN from finite input.

Derivatives do not go through the iterations.  The root is wrapped in a custom JVP:
dx = -(dfn/dargs . dargs) / (dfn/dx) at the converged x.  So jax.jvp, jax.jacfwd and
jax.grad of anything built on a root are exact derivatives of the *solution*, and a
root nested inside another root's fn is differentiated correctly as well.

The second output is a float flag (1.0 converged, 0.0 not) for the caller's cutback
logic; its tangent is zero.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import Any

import jax
import jax.numpy as jnp

Fn = Callable[[jax.Array, Any], jax.Array]


def _value_and_slope(fn: Fn, x, args):
    one = jnp.ones_like(x)
    return jax.jvp(lambda z: fn(z, args), (x,), (one,))


def bracketed_newton(fn: Fn, args, bracket, x0, xtol, ftol, maxiter, known=False):
    """The safeguarded iteration in ``bracket = (lo, hi)``, not differentiated (its
    caller differentiates the solution, as :func:`root_scalar` does): at most ``maxiter + 1``
    evaluations of fn, the first at x0.  fn is evaluated in one place only, the loop body
    (the first pass evaluates x0): a root nested inside fn is traced and compiled once,
    not once per evaluation site.
    ``known`` (bool scalar): x0 is already the root (found otherwise); it is returned
    without evaluating fn, so under vmap the loop runs only as long as some point of the
    batch still needs it."""
    lo, hi = bracket
    x0 = jnp.clip(x0, lo, hi)

    def cond(c):
        it, done = c[-2], c[-1]
        return (~done) & (it <= maxiter)

    def body(c):
        x, x_last, _, _, lo, hi, it, _ = c  # x: the point to evaluate now
        f, d = _value_and_slope(fn, x, args)
        finite = jnp.isfinite(f)
        first = it == 0
        # A non-finite residual is treated as "too far right" (overflow of a steep law);
        # at x0, a residual <= 0 moves the left end.
        go_right = jnp.where(first, f <= 0.0, finite & (f <= 0.0))
        lo = jnp.where(go_right, x, lo)
        hi = jnp.where(go_right, hi, x)
        f = jnp.where(finite, f, jnp.inf)
        small = (jnp.abs(f) <= ftol) | (hi - lo <= xtol)
        done = finite & (small | (~first & (jnp.abs(x - x_last) <= xtol)))
        step = f / jnp.where(d > 0.0, d, 1.0)
        xn = x - step
        newton_ok = jnp.isfinite(xn) & (d > 0.0) & (xn > lo) & (xn < hi)
        xn = jnp.where(newton_ok, xn, 0.5 * (lo + hi))
        return xn, x, f, d, lo, hi, it + 1, done

    zero = jnp.zeros_like(x0)
    init = (x0, x0, zero, zero, lo, hi, jnp.asarray(0), jnp.asarray(known))
    _, x, _, _, _, _, _, done = jax.lax.while_loop(cond, body, init)
    return x, done & jnp.isfinite(x)


@partial(jax.custom_jvp, nondiff_argnums=(0,))
def root_scalar(fn: Fn, args, lo, hi, x0, xtol, ftol, maxiter):
    """Root of increasing fn(., args) in [lo, hi]; returns (x, converged as 1.0/0.0).

    ``lo, hi, x0, xtol, ftol`` are scalars (may depend on args; they do not affect the
    root, so they carry no derivative); ``maxiter`` an int scalar.
    """
    sg = jax.lax.stop_gradient
    x, conv = bracketed_newton(fn, args, (sg(lo), sg(hi)), sg(x0), sg(xtol), sg(ftol), maxiter)
    return x, conv.astype(x.dtype)


@root_scalar.defjvp
def _root_scalar_jvp(fn, primals, tangents):
    args = primals[0]
    dargs = tangents[0]
    x, conv = root_scalar(fn, *primals)
    x = jax.lax.stop_gradient(x)
    _, dfdx = _value_and_slope(fn, x, args)
    _, dfda = jax.jvp(lambda a: fn(x, a), (args,), (dargs,))
    safe = jnp.where(dfdx != 0.0, dfdx, 1.0)
    dx = jnp.where(dfdx != 0.0, -dfda / safe, 0.0)
    return (x, conv), (dx, jnp.zeros_like(conv))
