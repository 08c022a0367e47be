"""Newton's method with backtracking line search for one load step, inside jit.

Thesis Fig. 5.2, made robust: each iteration solves J dx = -R, then backtracks
(alpha = 1, 1/2, 1/4, ...) until ||R(x + alpha dx)|| <= (1 - 1e-4 alpha) ||R(x)|| and
the trial state is valid.  Convergence: ||R|| <= rtol * F, where F is the force scale of
the step (the largest of the root-sum-square of the element force vectors, the norm of
the contact forces and that of the external loads), so the test is relative to the forces
actually carried.

Failures are status codes (see jaxform.formulations): the caller cuts the step back.

:func:`modified_newton` (:class:`ModifiedNewton`) keeps one factorization
across iterations and load steps and refreshes it (assembly + factorization + an exact
Newton step) when a step with it contracts ||R|| by less than 2x (that step is rejected)
or by less than 10x (that step is kept).  On large sparse systems the triangular solves
with a kept klujax factorization cost a small fraction of a factorization, so most
iterations cost a residual and those solves; the root is the same to rtol.  With
``anderson_depth`` > 0 the steps with a kept factorization are Anderson-accelerated: each
mixes the new step with the last few (a multisecant correction of the kept J^-1, one
small least-squares problem per iteration), a mixed step that does not contract 2x is
retried plainly before anything is refactored, and a kept step refreshes the next
iteration below a 3.3x contraction (mixed steps contract less evenly).

:func:`solve_implicit` is the same Newton solve, differentiated by the implicit function
theorem instead of through its iterations: at the converged x*, R(x*, a) = 0 gives
dx*/da = -J^-1 dR/da, so a reverse pass needs one solve with the transposed Jacobian
of the converged step (y = J^-T xbar) and one VJP of the residual with respect to the
arguments (abar = -y^T dR/da).  The solve's auxiliary output (the new Gauss state,
aux = G(x*, a)) is differentiated too: xbar gains (dG/dx)^T auxbar before the solve and
abar gains (dG/da)^T auxbar.  Per step the reverse pass costs one Jacobian assembly
(forward mode over the element dofs, whose tangents also give (dG/dx)^T auxbar), one
transposed solve, and one linearization of (R, G) in the arguments transposed once with
the cotangent (-y, auxbar).  The transposed solve factors J(x*) unless the forward pass
kept a factorization of a nearby Jacobian (``adjoint_fac``: the last Newton iteration's,
one step from x*); then it is iterative refinement with that one (:func:`adjoint_solve`:
a few triangular solves and products with J^T, to a componentwise backward error of a
few ulps), and a new factorization only where refinement stalls.  Where R is only
piecewise smooth (contact and friction switch between branches at an active-set change),
the derivative is that of the branch active at x*: exact away from a switch, one-sided
at it.

Each call site of ``residual`` is compiled separately (each costs about a second of XLA
time), so a solve evaluates it at one site (:func:`_trials`): the first pass of its loop
takes the start (x0, else the fallback) there, each later one the line search's trial
points; and an iteration's Jacobian is that at the iterate whose residual
the solve holds already (``jacobian(x, aux)``, given the residual's auxiliary output at
x: the element Jacobians reuse its local solves), with no residual of its own.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import partial
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from jaxform.status import NEWTON_NOT_CONVERGED, OK

STALE_PER_ITERATION = 3  # modified Newton: iterations with a kept factorization allowed
# per iteration with a new one, on top of it
# 'auto' picks modified Newton on the sparse backend from here even where the scene
# remeshes (below it, only on a scene that keeps its mesh: newton_variant)
MODIFIED_MIN_UNKNOWNS = 5_000


@dataclass(frozen=True)
class FullNewton:
    """Newton's method with a new Jacobian and factorization every iteration
    (:func:`newton`).  Keeps no factorization from one step to the next."""

    keeps_factorization: ClassVar[bool] = False

    def total_iterations(self, max_iterations: int) -> int:
        """Iterations of any kind a solve may take."""
        return max_iterations

    def jacobians(self, iterations, fac_before, fac_after):
        """Iterations of a solve with a new Jacobian: all of them."""
        return iterations

    def factorization(self, linear, n: int, dtype):
        """The factorization a run starts with and carries across steps: none."""
        return None

    def solve(self, fns: NewtonFunctions, x0, settings: NewtonSettings, x_fallback=None,
              kept: Kept | None = None, give_up=None):  # fmt: skip
        """:func:`newton` (factoring through ``kept`` where given; stopping early where it
        stalls and ``give_up``, :func:`stalled`)."""
        return newton(fns.residual, fns.jacobian, fns.linear_solve, x0, settings, x_fallback,
                      kept, give_up)  # fmt: skip


@dataclass(frozen=True)
class ModifiedNewton:
    """Modified Newton (:func:`modified_newton`): a factorization kept across iterations and
    load steps, refreshed when it stops contracting.  ``accept_ratio``: a step with the kept
    factorization is taken when it contracts ||R|| to at most this; ``refresh_ratio``: one
    that contracts less refreshes the next iteration (None: :attr:`refresh_below`);
    ``anderson_depth``: each step with a kept factorization is mixed with up to that many
    earlier ones (Anderson acceleration, :func:`_anderson_step`; 0: plain steps).  A solve
    may take up to ``STALE_PER_ITERATION`` iterations with a kept factorization per
    iteration with a new one, on top of it."""

    keeps_factorization: ClassVar[bool] = True

    accept_ratio: float = 0.5
    refresh_ratio: float | None = None
    anderson_depth: int = 0

    @property
    def refresh_below(self) -> float:
        """A kept-factorization step contracting ||R|| by less than this refreshes the next
        iteration: ``refresh_ratio``, else 0.1 for plain steps and 0.3 for mixed ones (they
        contract unevenly from one step to the next; chosen on the seed and friction scenes,
        docs/benchmarks.md)."""
        if self.refresh_ratio is not None:
            return self.refresh_ratio
        return 0.3 if self.anderson_depth > 0 else 0.1

    def total_iterations(self, max_iterations: int) -> int:
        """Iterations of any kind a solve may take: ``max_iterations`` with a new Jacobian
        and up to ``STALE_PER_ITERATION`` times as many with a kept one."""
        return max_iterations * (1 + STALE_PER_ITERATION)

    def jacobians(self, iterations, fac_before, fac_after):
        """Iterations of a solve with a new Jacobian: the factorizations it made (the
        count its kept factorization carries)."""
        return fac_after.count - fac_before.count

    def factorization(self, linear, n: int, dtype):
        """The factorization a run starts with and carries across steps: an empty one of
        ``linear`` (the first iteration factors)."""
        return linear.empty_factorization(n, dtype)

    def solve(self, fns: NewtonFunctions, x0, settings: NewtonSettings, x_fallback=None,
              kept: Kept | None = None, give_up=None):  # fmt: skip
        """:func:`modified_newton` from the factorization ``kept`` (stopping early where it
        stalls and ``give_up``, :func:`stalled`)."""
        return modified_newton(fns.residual, fns.jacobian, kept, x0, settings, x_fallback,
                               give_up)  # fmt: skip


NewtonVariant = FullNewton | ModifiedNewton
# the variants by their name in the config (solver.newton; 'auto' picks one by size)
VARIANTS = {"newton": FullNewton, "modified": ModifiedNewton}


def newton_variant(
    name: str, linear, n_unknowns: int, anderson_depth: int = 0, remeshes: bool = False
) -> NewtonVariant:
    """The Newton variant for ``solver.newton = name`` with the chosen linear solver
    (:class:`jaxform.linear.LinearSolver`) on ``n_unknowns`` unknowns: 'auto' picks modified
    Newton where the solver says it pays (klujax), on a scene that keeps its mesh at any
    size and on one that ``remeshes`` from MODIFIED_MIN_UNKNOWNS unknowns (below that,
    its new meshes' first steps and the flash's contact changes cost modified Newton
    more refreshes than full Newton's iterations: docs, benchmarks, "Scale and speed");
    full Newton otherwise.  Modified Newton needs a solver that keeps a factorization.
    ``anderson_depth``: modified Newton's (``solver.anderson_depth``)."""
    if name == "auto":
        pays = n_unknowns >= MODIFIED_MIN_UNKNOWNS or not remeshes
        name = "modified" if pays and linear.modified_when_large else "newton"
    if name not in VARIANTS:
        raise ValueError(f"solver.newton = {name!r}: must be one of auto, newton, modified")
    variant = VARIANTS[name]
    if variant.keeps_factorization and not linear.keeps_factorization:
        raise ValueError(
            f"solver.newton = '{name}' keeps a factorization, which the "
            f"'{linear.backend}' linear backend cannot: use solver.linear = 'dense', "
            f"'sparse' (klujax, CPU) or 'pardiso' (MKL, CPU), or solver.newton = 'newton'"
        )
    if variant.keeps_factorization:
        return ModifiedNewton(anderson_depth=anderson_depth)
    return variant()


@dataclass(frozen=True)
class NewtonSettings:
    """The Newton solve of a step: ``variant`` (:class:`FullNewton`, a new Jacobian every
    iteration; :class:`ModifiedNewton`, a factorization kept across iterations and load
    steps), ``max_iterations`` bounds the iterations with a new Jacobian (the variant says
    how many a solve may take in all), ``rtol`` the convergence test, ``line_search`` with
    up to ``max_backtracks`` halvings.  ``stall_iterations`` (0: off) and ``stall_ratio``:
    a solve that may give up (:func:`stalled`) stops, not converged, once its best
    ||R|| / F has not fallen below ``stall_ratio`` times the best of ``stall_iterations``
    iterations earlier."""

    max_iterations: int = 25
    rtol: float = 1e-10
    line_search: bool = True
    max_backtracks: int = 10
    variant: NewtonVariant = FullNewton()
    stall_iterations: int = 0
    stall_ratio: float = 0.9

    @property
    def max_total_iterations(self) -> int:
        """Iterations of any kind a solve may take (the history's length minus one)."""
        return self.variant.total_iterations(self.max_iterations)

    def exact(self) -> NewtonSettings:
        """These settings with full Newton (a differentiable run: the factorization modified
        Newton keeps is a handle that would have to live across a vmapped scan, and the
        gradient is the same, the reverse pass solving with the exact Jacobian)."""
        return replace(self, variant=FullNewton())


@dataclass(frozen=True)
class NewtonFunctions:
    """What a Newton solve evaluates: residual(x) -> (R, aux, code, scale); jacobian(x,
    aux) -> vals, the Jacobian at x given aux of residual(x); linear_solve(vals, b) -> the
    solution of J y = b (None where every solve goes through a kept factorization)."""

    residual: Callable
    jacobian: Callable
    linear_solve: Callable | None = None


def _blank(residual, x0):
    """Zeros shaped like residual(x0)'s outputs (R, aux, code, scale): a solve's values
    before its start is evaluated (the code OK, which is 0)."""
    out = jax.eval_shape(residual, x0)
    return jax.tree_util.tree_map(lambda a: jnp.zeros(a.shape, a.dtype), out)


def _trials(residual, point, bad, limit, held):
    """Evaluate the residual at trial points through its one call site in a solve:
    ``point(k, alpha)`` the k-th (alpha = 1, 1/2, 1/4, ...), taken once not
    ``bad(alpha, r, code)`` or once k = ``limit`` (traced).  ``held``: (done, x, R, aux,
    code, scale), returned as they are where done already.  Returns (x, R, aux, code,
    scale) of the trial taken."""

    def ls_cond(lc):
        return ~lc[2]

    def ls_body(lc):
        k, alpha = lc[0], lc[1]
        xt = point(k, alpha)
        rt, auxt, codet, scalet = residual(xt)
        done = ~(bad(alpha, rt, codet) & (k < limit))  # k trials done before this one
        return (k + 1, 0.5 * alpha, done, xt, rt, auxt, codet, scalet)

    x = held[1]
    lc0 = (jnp.asarray(0), jnp.asarray(1.0, x.dtype)) + tuple(held)
    return jax.lax.while_loop(ls_cond, ls_body, lc0)[3:]


def _start_point(x0, x_fallback):
    """(point of the start's trials: x0, then x_fallback; the start's trials after the
    first: 1 where there is a fallback, else 0)."""
    fallback = x0 if x_fallback is None else x_fallback

    def point(k):
        return jnp.where(k == 0, x0, fallback)

    return point, int(x_fallback is not None)


def stalled(hist, it, settings: NewtonSettings, give_up):
    """Whether a solve at iteration ``it`` (``hist[k]`` = ||R_k|| / F_k, inf where not
    reached) has stalled: ``give_up`` (traced: the caller can still cut the step) and the
    least residual so far is above ``settings.stall_ratio`` times the least of the first
    ``it - settings.stall_iterations + 1`` entries.  A step whose Newton solve crawls at
    that rate does not converge within its iterations (a line search that cuts most of
    every step, a residual that a contact switch blocks): stopping hands the step to the
    caller's cutback ``max_iterations - stall_iterations`` iterations sooner.  Off
    (False) where ``stall_iterations`` is 0 or ``give_up`` is None."""
    w = settings.stall_iterations
    if w <= 0 or give_up is None:
        return jnp.asarray(False)
    k = jnp.arange(hist.shape[0])
    best = jnp.min(jnp.where(k <= it, hist, jnp.inf))
    before = jnp.min(jnp.where(k <= it - w, hist, jnp.inf))
    return give_up & (it >= w) & (best > settings.stall_ratio * before)


@dataclass(frozen=True)
class Kept:
    """A factorization Newton keeps: ``factor(vals, old) -> fac`` makes a new one (freeing
    ``old``), ``solve_factored(fac, b)`` solves with it, ``fac`` is the one to start from."""

    factor: Callable
    solve_factored: Callable
    fac: object


def newton(
    residual,
    jacobian,
    linear_solve,
    x0,
    settings: NewtonSettings,
    x_fallback=None,
    kept: Kept | None = None,
    give_up=None,
):
    """Solve R(x) = 0 from x0 (or from x_fallback if x0 is not a valid state, e.g. a
    predictor that inverts an element).

    residual(x) -> (R, aux, code, scale); jacobian(x, aux) -> vals, the Jacobian at x
    given the auxiliary output of residual(x); linear_solve(vals, b) -> solution.  Returns
    (x, aux, iterations, code, history, fac) with history[k] = ||R_k|| / scale_k
    (NaN-free; inf where not reached).

    With ``kept`` (:class:`Kept`), each iteration factors and then solves with the factors
    (the same work as linear_solve), and the factorization of the last iteration is
    returned as ``fac`` (``kept.fac`` if there was none), for the caller to reuse: the
    Jacobian of the iterate before the root, within one Newton step of it.  Without it
    ``fac`` is None.  ``give_up`` (traced bool, or None): the solve may stop, not
    converged, where it stalls (:func:`stalled`).
    """
    s = settings
    r0, aux0, code0, scale0 = _blank(residual, x0)
    start, n_start = _start_point(x0, x_fallback)
    max_bt = s.max_backtracks if s.line_search else 0

    def direction(x, r, aux, fac):  # Newton's step from x (R(x) = r, held)
        vals = jacobian(x, aux)
        if kept is None:
            return linear_solve(vals, -r), fac
        fac = kept.factor(vals, fac)
        return kept.solve_factored(fac, -r), fac

    def body(c):
        # the trials: the start at the first pass, then the line search along dx from x
        x, r, aux, scale, dx, fac, it, code, rnorm, _, hist, _, started = c

        def point(k, alpha):  # alpha = 1, 1/2, ... (1 only without the line search)
            return jnp.where(started, x + alpha * dx, start(k))

        def bad(alpha, rt, codet):  # invalid, or (an iteration's) decrease insufficient
            worse = jnp.linalg.norm(rt) > (1.0 - 1e-4 * alpha) * rnorm
            return (codet != OK) | (started & worse)

        limit = jnp.where(started, max_bt, n_start)
        held = (jnp.asarray(False), x, r, aux, code, scale)
        x, r, aux, code, scale = _trials(residual, point, bad, limit, held)
        rnorm = jnp.linalg.norm(r)
        conv = (code == OK) & (rnorm <= s.rtol * scale)
        it = it + started.astype(it.dtype)
        hist = hist.at[it].set(rnorm / scale)
        code = jnp.where(jnp.isfinite(dx).all(), code, jnp.maximum(code, 4))
        # the next step, where the solve goes on
        going = (~conv) & (code == OK) & (it < s.max_iterations)
        going = going & ~stalled(hist, it, s, give_up)
        no_step = (jnp.zeros_like(x), fac)
        dx, fac = jax.lax.cond(going, lambda: direction(x, r, aux, fac), lambda: no_step)
        return x, r, aux, scale, dx, fac, it, code, rnorm, conv, hist, going, jnp.asarray(True)

    fac0 = None if kept is None else kept.fac
    hist0 = jnp.full(s.max_iterations + 1, jnp.inf)
    zero, yes, no = jnp.zeros((), r0.dtype), jnp.asarray(True), jnp.asarray(False)
    init = (x0, r0, aux0, scale0, jnp.zeros_like(x0), fac0, jnp.asarray(0), code0, zero, no,
            hist0, yes, no)  # fmt: skip
    out = jax.lax.while_loop(lambda c: c[11], body, init)
    x, _, aux, _, _, fac, it, code, _, conv, hist, _, _ = out
    code = jnp.where(conv, OK, jnp.where(code == OK, NEWTON_NOT_CONVERGED, code))
    return x, aux, it, code, hist, fac


def _anderson_step(mem, x, f):
    """Anderson acceleration (type II) of the fixed-point map x -> x + f(x), where
    f(x) = -J_old^-1 R(x) is modified Newton's step with the kept factorization: the step
    f - (dX + dF) gamma, with gamma minimizing ||f - dF gamma|| over the differences of
    the last iterates (dX: of x, dF: of f; all with the same factorization).  A linear
    residual reaches its root in at most depth + 1 steps of this (a multisecant update of
    J_old^-1); a nonlinear one contracts faster than with plain steps.  ``mem`` holds the
    differences (newest first), the last iterate and its f, and how many differences are
    usable (-1: no last iterate, which empties it: the rest is then never read).  Returns
    the step and the memory with (x, f) pushed."""
    d_x, d_f, x_last, f_last, n = mem["dx"], mem["df"], mem["x"], mem["f"], mem["n"]
    depth = d_x.shape[0]
    has_last = n >= 0
    d_x = jnp.where(has_last, jnp.roll(d_x, 1, axis=0).at[0].set(x - x_last), d_x)
    d_f = jnp.where(has_last, jnp.roll(d_f, 1, axis=0).at[0].set(f - f_last), d_f)
    n = jnp.where(has_last, jnp.minimum(n + 1, depth), 0)
    use = jnp.arange(depth) < n
    both = use[:, None] & use[None, :]
    gram = jnp.where(both, d_f @ d_f.T, 0.0)
    reg = 1e-12 * jnp.max(jnp.diag(gram)) + jnp.finfo(gram.dtype).tiny
    gram = gram + jnp.diag(jnp.where(use, reg, 1.0))
    gamma = jnp.where(use, jnp.linalg.solve(gram, jnp.where(use, d_f @ f, 0.0)), 0.0)
    step = f - (d_x + d_f).T @ gamma
    return step, dict(dx=d_x, df=d_f, x=x, f=f, n=n)


def _anderson_memory(depth, x):
    """An empty memory for :func:`_anderson_step` (no last iterate)."""
    rows = jnp.zeros((depth,) + x.shape, x.dtype)
    return dict(dx=rows, df=rows, x=jnp.zeros_like(x), f=jnp.zeros_like(x), n=jnp.asarray(-1))


def modified_newton(
    residual,
    jacobian,
    kept: Kept,
    x0,
    settings: NewtonSettings,
    x_fallback=None,
    give_up=None,
):
    """Modified Newton: solve R(x) = 0 with a factorization kept from earlier iterations
    (of this solve or of earlier load steps), refreshed only when it stops working.

    An iteration solves J_old dx = -R(x) with the kept factorization (``kept.fac`` on
    entry, possibly from another state).  The full step is accepted when ||R|| falls to
    <= ``accept_ratio`` x its value; otherwise it is rejected (x unchanged, the iteration
    counts) and the next iteration refreshes: assembles the Jacobian at x, factors it
    (``kept.factor(vals, old) -> fac``, which frees the old one) and takes an exact Newton step
    with the backtracking line search of :func:`newton`.  An accepted step that contracted
    by less than ``settingv.refresh_below`` also refreshes the next iteration.  With
    ``anderson_depth`` > 0 the steps with a kept factorization are Anderson-accelerated
    (:func:`_anderson_step`; a refresh starts its memory afresh, and a rejected mixed step
    is retried plainly with the same factorization instead of refreshing).  Convergence and
    failure codes as in :func:`newton`; the converged x is the same root to ``rtol`` (the
    factorization only changes the path).  ``give_up``: as for :func:`newton`, over all
    its iterations.  Returns (x, aux, iterations, code, history, fac).
    """
    s, v = settings, settings.variant
    factor, solve_factored, fac0 = kept.factor, kept.solve_factored, kept.fac
    r0, aux0, code0, scale0 = _blank(residual, x0)
    start, n_start = _start_point(x0, x_fallback)
    count0 = fac0.count
    max_bt = s.max_backtracks if s.line_search else 0

    def direction(c, fresh):
        """The step from c's x (its residual held): with the kept factorization, or a new
        one where ``fresh``; Anderson-mixed where on (a refresh empties the memory)."""
        x, r, fac = c["x"], c["r"], c["fac"]
        fac = jax.lax.cond(fresh, lambda: factor(jacobian(x, c["aux"]), fac), lambda: fac)
        dx = jax.lax.cond(
            fac.valid, lambda: solve_factored(fac, -r), lambda: jnp.full_like(r, jnp.nan)
        )  # never solve with no factors
        out = dict(dx=dx, fac=fac, fresh=fresh)
        if v.anderson_depth > 0:  # a refreshed step is Newton's, and starts the memory
            mem = dict(c["aa"], n=jnp.where(fresh, -1, c["aa"]["n"]))  # n < 0: empty
            out["dx"], out["aa"] = _anderson_step(mem, x, dx)
        return out

    def body(c):
        # the trials: the start at the first pass, then the step dx from x (refreshed
        # steps with the line search, stale ones once)
        x, r, aux, scale, dx, started = c["x"], c["r"], c["aux"], c["scale"], c["dx"], c["started"]
        fresh = c["fresh"]
        rnorm = jnp.linalg.norm(r)
        finite = jnp.isfinite(dx).all()

        def point(k, alpha):
            return jnp.where(started, x + alpha * dx, start(k))

        def bad(alpha, rt, codet):
            worse = jnp.linalg.norm(rt) > (1.0 - 1e-4 * alpha) * rnorm
            return (codet != OK) | (started & worse)

        limit = jnp.where(started, jnp.where(fresh, max_bt, 0), n_start)
        held = (jnp.asarray(False), x, r, aux, c["code"], scale)
        xt, rt, auxt, codet, scalet = _trials(residual, point, bad, limit, held)
        rtn = jnp.linalg.norm(rt)
        ratio = rtn / rnorm
        # a stale step that does not contract (or leaves the valid states) is rejected;
        # a refreshed one is taken as in newton(); the start is taken
        reject = started & (~fresh) & ((codet != OK) | ~finite | ~(ratio <= v.accept_ratio))
        code = jnp.where(reject, OK, jnp.where(finite, codet, jnp.maximum(codet, 4)))
        conv = ~reject & (codet == OK) & (rtn <= s.rtol * scalet)
        it = c["it"] + started.astype(c["it"].dtype)
        new = dict(
            x=jnp.where(reject, x, xt),
            r=jnp.where(reject, r, rt),
            aux=jax.tree_util.tree_map(lambda u, w: jnp.where(reject, w, u), auxt, aux),
            scale=jnp.where(reject, scale, scalet),
            it=it,
            code=code,
            conv=conv,
            hist=c["hist"].at[it].set(jnp.where(reject, rnorm / scale, rtn / scalet)),
            fac=c["fac"],
            started=jnp.asarray(True),
        )
        refresh = started & (reject | (ratio > v.refresh_below))
        if v.anderson_depth > 0:
            # a mixed step that is rejected is retried plainly, with the same factorization
            mixed = reject & (c["aa"]["n"] > 0)
            refresh = jnp.where(mixed, False, refresh)
            new["aa"] = dict(c["aa"], n=jnp.where(mixed, -1, c["aa"]["n"]))
        # the next step, where the solve goes on
        going = (
            (~conv)
            & (code == OK)
            & (it < s.max_total_iterations)
            & ((new["fac"].count - count0 < s.max_iterations) | ~refresh)
            & ~stalled(new["hist"], it, s, give_up)
        )
        fresh = going & (refresh | ~new["fac"].valid)
        none = dict(dx=jnp.zeros_like(x), fac=new["fac"], fresh=fresh)
        if v.anderson_depth > 0:
            none["aa"] = new["aa"]
        nxt = jax.lax.cond(going, lambda: direction(new, fresh), lambda: none)
        return dict(new, **nxt, going=going)

    init = dict(
        x=x0,
        r=r0,
        aux=aux0,
        scale=scale0,
        dx=jnp.zeros_like(x0),
        fresh=jnp.asarray(False),
        it=jnp.asarray(0),
        code=code0,
        conv=jnp.asarray(False),
        hist=jnp.full(s.max_total_iterations + 1, jnp.inf),
        fac=fac0,
        going=jnp.asarray(True),
        started=jnp.asarray(False),
    )
    if v.anderson_depth > 0:
        init["aa"] = _anderson_memory(v.anderson_depth, x0)
    out = jax.lax.while_loop(lambda c: c["going"], body, init)
    code = jnp.where(
        out["conv"], OK, jnp.where(out["code"] == OK, NEWTON_NOT_CONVERGED, out["code"])
    )
    return out["x"], out["aux"], out["it"], code, out["hist"], out["fac"]


REFINE_MAX_STEPS = 8  # refinement steps with a kept factorization before factoring afresh
REFINE_TARGET = 4.0 * np.finfo(np.float64).eps  # refinement goes on to this backward error
REFINE_TOL = 1e-14  # ... or until it stalls, and is accepted if it reached this


def refined_solve(
    solve_near,
    matvec,
    abs_matvec,
    b,
    max_steps: int = REFINE_MAX_STEPS,
    target: float = REFINE_TARGET,
    tol: float = REFINE_TOL,
):
    """Solve A y = b by iterative refinement, y <- y + M(b - A y), where M = ``solve_near``
    applies the inverse of a nearby matrix (a factorization of it), ``matvec`` applies A
    and ``abs_matvec`` |A| (entrywise absolute values).

    The measure is the componentwise backward error max_i |b - A y|_i / (|A| |y| + |b|)_i
    (Oettli-Prager: the smallest relative change of each entry of A and b that makes y
    exact), which rows of very different scale (displacements and contact multipliers)
    do not dilute as a normwise one does.  Refinement goes on while it is above
    ``target`` (a few ulps, what a direct solve reaches), for at most ``max_steps``, and
    while each step at least halves it (each contracts the error by about ||I - M A||: a
    factorization that is not of a nearby matrix stalls at once).  Converged: at most
    ``tol``.  Returns (y, steps, converged)."""

    def backward_error(y, r):
        den = abs_matvec(jnp.abs(y)) + jnp.abs(b)
        ratio = jnp.abs(r) / jnp.where(den > 0, den, 1.0)
        return jnp.max(jnp.where(den > 0, ratio, jnp.where(r == 0, 0.0, jnp.inf)))

    def cond(c):
        k, _, _, e, e_prev = c
        return (e > target) & (k < max_steps) & (e <= 0.5 * e_prev)

    def body(c):
        k, y, r, e, _ = c
        y = y + solve_near(r)
        r = b - matvec(y)
        return k + 1, y, r, backward_error(y, r), e

    y0 = jnp.zeros_like(b)
    init = (jnp.asarray(0), y0, b, backward_error(y0, b), jnp.asarray(jnp.inf, b.dtype))
    k, y, _, e, _ = jax.lax.while_loop(cond, body, init)
    return y, k, e <= tol


def adjoint_solve(linear, vals, b, args, fac=None, use=None):
    """y with J^T y = b, J given by ``vals``: by :func:`refined_solve` with the kept
    factorization ``fac`` of a nearby Jacobian where ``use`` (a traced bool), else, or
    where refinement does not reach the tolerance, by a fresh transposed solve."""

    def fresh():
        return linear(vals, b, args, True)

    if fac is None:
        return fresh()

    def refined():
        return refined_solve(
            lambda r: linear.solve_factored(fac, r, args, True),
            lambda y: linear.matvec(vals, y, args, True),
            lambda y: linear.matvec(jnp.abs(vals), y, args, True),
            b,
        )

    def skipped():
        return jnp.zeros_like(b), jnp.asarray(0), jnp.asarray(False)

    y, _, ok = jax.lax.cond(use, refined, skipped)
    return jax.lax.cond(ok, lambda: y, fresh)


@dataclass(frozen=True)
class ImplicitProblem:
    """The static part of an implicitly differentiated solve (hashable): the functions and
    the linear algebra of :func:`solve_implicit`, and the Newton settings."""

    fn: Callable
    fn_jac: Callable
    fn_adj: Callable
    linear: object
    settings: NewtonSettings


@partial(jax.custom_vjp, nondiff_argnums=(0,))
def solve_implicit(
    problem: ImplicitProblem,
    x0,
    x_fallback,
    args,
    fac=None,
    adjoint_fac=None,
    give_up=None,
):
    """Newton from x0 (x_fallback if x0 is invalid) on fn(., args) = 0, differentiable in
    ``args`` by the implicit function theorem (x0, x_fallback and the factorizations get no
    derivative).

    ``problem`` (:class:`ImplicitProblem`): fn(x, args) -> (R, aux, code, scale);
    fn_jac(x, args, aux) -> vals, the Jacobian at x given aux of fn(x, args); fn_adj(x,
    args, aux, aux_bar) -> (vals, (daux/dx)^T aux_bar) at the root x with its aux, for
    the reverse pass;
    linear(vals, b, args, transpose) -> solution of J y = b (or J^T y = b); where
    factorizations are kept also linear.factor(vals, args, old) -> a
    :class:`jaxform.linear.Factorization` (freeing ``old``), linear.solve_factored(fac, b,
    args, transpose) and linear.matvec(vals, y, args, transpose).

    ``fac``: with :class:`ModifiedNewton` (``problem.settings.variant``) the factorization
    to start from; with :class:`FullNewton`, if given, each iteration factors and solves
    with the factors (freeing ``fac`` at the first) and the last iteration's factorization
    is returned (see :func:`newton`).  Either way the caller owns the one returned.
    ``adjoint_fac``: a factorization of a Jacobian near this root, which the caller keeps
    alive through the reverse pass; where valid and this solve took no iteration (x0 was
    already the root it was factored near), the reverse pass solves by
    :func:`adjoint_solve` with it instead of factoring J(x*) again.  ``give_up`` (traced
    bool or None): the solve may stop early where it stalls (:func:`stalled`; the caller
    then cuts the step).

    Returns (x, aux, iterations, code, history, fac) like :func:`newton`.  The functions
    must be hashable and close over no traced value: everything traced goes through
    ``args``.  The reverse pass solves with the exact Jacobian at the converged x whichever
    the variant (refined to a componentwise backward error of a few ulps when it reuses a
    factorization).
    """
    fn, fn_jac, linear, settings = problem.fn, problem.fn_jac, problem.linear, problem.settings
    kept = None
    if fac is not None:
        kept = Kept(
            lambda vals, old: linear.factor(vals, args, old),
            lambda f, b: linear.solve_factored(f, b, args),
            fac,
        )
    fns = NewtonFunctions(
        lambda x: fn(x, args),
        lambda x, aux: fn_jac(x, args, aux),
        lambda vals, b: linear(vals, b, args, False),
    )
    return settings.variant.solve(fns, x0, settings, x_fallback, kept, give_up)


def _solve_implicit_fwd(problem, x0, x_fallback, args, fac=None, adjoint_fac=None, give_up=None):
    out = solve_implicit(problem, x0, x_fallback, args, fac, adjoint_fac, give_up)
    return out, (out[0], out[1], out[2], args, fac, adjoint_fac, give_up)


def _solve_implicit_bwd(problem, res, cot):
    """xbar_total = xbar + (dG/dx)^T auxbar;  J^T y = xbar_total;
    abar = (dG/da)^T auxbar - (dR/da)^T y.

    The x-derivatives come from forward mode (fn_adj: the Jacobian assembly, whose
    tangents carry dG/dx too), so the reverse pass through the residual is taken with
    respect to ``args`` only, and once, with the cotangent (-y, auxbar): one
    linearization and one transposition instead of a linearization in (x, args) and two
    transpositions (measured on the seed scene: see experiments/bench_gradient.py)."""
    fn, fn_adj, linear = problem.fn, problem.fn_adj, problem.linear
    x, aux, its, args, fac, adjoint_fac, give_up = res
    x_bar, aux_bar = cot[0], cot[1]
    vals, xg_bar = fn_adj(x, args, aux, aux_bar)
    use = None if adjoint_fac is None else adjoint_fac.valid & (its == 0)
    y = adjoint_solve(linear, vals, x_bar + xg_bar, args, adjoint_fac, use)

    def r_and_aux(a):
        r, aux, _, _ = fn(x, a)
        return r, aux

    _, vjp = jax.vjp(r_and_aux, args)
    (a_bar,) = vjp((-y, aux_bar))
    return (
        jnp.zeros_like(x),
        jnp.zeros_like(x),
        a_bar,
        _zero_cotangent(fac),
        _zero_cotangent(adjoint_fac),
        _zero_cotangent(give_up),
    )


def _zero_cotangent(tree):
    """Zero cotangents for a non-differentiated input (float0 for integer leaves)."""

    def zero(a):
        if jnp.issubdtype(a.dtype, jnp.inexact):
            return jnp.zeros_like(a)
        return np.zeros(a.shape, dtype=jax.dtypes.float0)

    return jax.tree_util.tree_map(zero, tree)


solve_implicit.defvjp(_solve_implicit_fwd, _solve_implicit_bwd)
