"""Bounded gradient-based design loops with optax: L-BFGS or Adam.

The caller owns nothing here but the problem: :func:`optimize` runs on the host, one
compiled gradient evaluation per trial design, and

* keeps every design inside its box bounds (projection after each step, optax's
  ``projection_box``);
* L-BFGS: optax's two-loop recursion (``scale_by_lbfgs``) gives the direction, a
  backtracking (Armijo) line search on the projected path picks the step; the first
  step is limited to a fraction of the bound box (``step_max_fraction``, a quarter by
  default) so that a large gradient cannot throw the design across it; a direction that
  does not descend (curvature pairs taken across a kink of the objective: a contact
  switch) is replaced by -g, scaled so that its largest component moves that fraction of
  its box, and the memory is cleared;
* Adam: optax's ``adam`` with the configured step size;
* a trial design whose run fails (:class:`GradientRunError`: a load step did not
  converge) is treated as a rejected step and the step is halved, so one bad trial
  never ends the loop;
* a problem with a ``forward_value`` (a process's) has each trial's objective from its
  forward run and the gradient only where a trial is accepted, so that a rejected trial
  costs one simulation (a design counts one simulation, with or without its gradient);
* stops after ``iterations`` accepted steps, or when the line search cannot decrease the
  objective (a stationary point within the bounds).

Returns the history: per iteration the objective, the norm of the projected gradient and
the design.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxform import program_store
from jaxform.gradients import GradientRunError


@dataclass(frozen=True)
class OptimizerSettings:
    """How :func:`optimize` minimizes.

    Arguments:
        method: ``lbfgs`` (L-BFGS with an Armijo backtracking line search) or ``adam``.
        iterations: optimizer iterations; learning_rate: Adam's step size.
        max_backtracks, armijo: line-search halvings and sufficient-decrease factor.
        step_max_fraction: L-BFGS: the most any variable moves in one step, as a fraction
            of its bound box (a restart's steepest descent: the largest moves that much).

    Returns:
        the settings (frozen) to pass to :func:`optimize`.
    """

    method: str = "lbfgs"  # 'lbfgs' | 'adam'
    iterations: int = 20
    learning_rate: float = 0.05  # Adam
    max_backtracks: int = 8
    armijo: float = 1e-4
    step_max_fraction: float = 0.25  # L-BFGS: the most a variable moves, of its box

    def minimize(self, problem, design=None, progress=None, history=None) -> DesignHistory:
        return gradient_loop(problem, self, design, progress, history)


@dataclass
class DesignHistory:
    """Rows of a design loop: per accepted iteration (gradient optimizers) or per run
    (sampling optimizers, :mod:`jaxform.design.sampling`) the objective (NaN: the run
    failed), the projected gradient norm (NaN without gradients), the design and the
    runs used so far (``simulations``: a gradient evaluation is one run)."""

    objective: list[float] = field(default_factory=list)
    grad_norm: list[float] = field(default_factory=list)
    designs: list[dict] = field(default_factory=list)
    simulations: list[int] = field(default_factory=list)
    evaluations: int = 0
    rejected: int = 0
    restarts: int = 0  # L-BFGS directions that were not descent directions (-g instead)
    stop_reason: str = ""

    @property
    def best(self) -> int:
        """The row of the lowest objective (the first such; failed runs never)."""
        f = np.where(np.isfinite(self.objective), self.objective, np.inf)
        return int(np.argmin(f))

    def best_so_far(self) -> np.ndarray:
        """The lowest objective up to each row (inf before the first run that succeeded)."""
        f = np.where(np.isfinite(self.objective), self.objective, np.inf)
        return np.minimum.accumulate(f)

    def columns(self, problem) -> dict[str, np.ndarray]:
        """Per row: iteration, simulations (runs used so far), objective, best_objective
        (the lowest so far), grad_norm and the design's physical values
        (``problem.physical``), as CSV columns."""
        cols = {
            "iteration": np.arange(len(self.objective)),
            "simulations": np.array(self.simulations),
            "objective": np.array(self.objective),
            "best_objective": self.best_so_far(),
            "grad_norm": np.array(self.grad_norm),
        }
        phys = [problem.physical(u) for u in self.designs]
        cols.update({key: np.array([p[key] for p in phys]) for key in phys[0]})
        return cols


def _flat(tree):
    return np.concatenate([np.ravel(np.asarray(v)) for v in jax.tree_util.tree_leaves(tree)])


def _projected_grad_norm(u, g, lo, hi):
    """Norm of the gradient components that can still move the design (KKT measure)."""
    uf, gf, lf, hf = (_flat(t) for t in (u, g, lo, hi))
    free = ~(((uf <= lf) & (gf > 0)) | ((uf >= hf) & (gf < 0)))
    return float(np.linalg.norm(gf[free]))


def optimize(
    problem,
    settings=OptimizerSettings(),
    design=None,
    progress: Callable[[int, float, float, dict], None] | None = None,
    history: DesignHistory | None = None,
) -> DesignHistory:
    """Minimize ``problem``'s objective within its bounds.

    Arguments:
        problem: a :class:`jaxform.design.problem.DesignProblem` (or anything with
            ``start``, ``bounds()``, ``value`` and, for gradients, ``value_and_grad``).
        settings: :class:`OptimizerSettings` (gradients: ``lbfgs`` with a backtracking
            line search, or ``adam``) or a sampling optimizer of
            :mod:`jaxform.design.sampling` (:class:`~jaxform.design.sampling.LhsRsm`,
            :class:`~jaxform.design.sampling.CmaEs`): any object with ``minimize``.
        design: the start (default ``problem.start``).
        progress: called after each accepted iteration with (iteration, objective,
            projected gradient norm, design); a sampling optimizer calls it after each
            run with (runs, objective, best objective so far, design).
        history: the :class:`DesignHistory` to fill (empty; default a new one): the caller
            can read it from ``progress``, e.g. to write the rows so far.

    Returns:
        the :class:`DesignHistory`: objective, gradient norm, design and runs used per
        iteration (per run for sampling), evaluations, rejected trials, why it stopped.
    """
    return settings.minimize(problem, design, progress, history)


def gradient_loop(problem, settings: OptimizerSettings, design=None, progress=None, history=None):
    """The projected L-BFGS / Adam loop of :func:`optimize` (module docstring)."""
    if settings.method not in ("lbfgs", "adam"):
        raise ValueError(f"design.optimizer = {settings.method!r}: must be 'lbfgs' or 'adam'")
    lo, hi = problem.bounds()
    project = jax.jit(lambda u: optax.projections.projection_box(u, lo, hi))
    u = project(problem.start if design is None else design)
    hist = DesignHistory() if history is None else history

    forward = getattr(problem, "forward_value", None)

    def evaluate(u, counted=True):
        hist.evaluations += int(counted)
        program_store.make_room()  # each design's meshes compile programs of their own
        val, g, _ = problem.value_and_grad(u)
        return float(val), g

    def trial_value(u):
        """A trial's objective: its forward run where the problem has one (a process:
        a rejected trial costs a simulation, not a gradient run and a new plan), else its
        value and gradient at once."""
        if forward is None:
            return evaluate(u)
        hist.evaluations += 1
        return float(forward(u)), None

    val, g = evaluate(u)
    record(hist, u, val, g, lo, hi, progress)
    if settings.method == "adam":
        opt = optax.adam(settings.learning_rate)
    else:
        opt = optax.scale_by_lbfgs()
    state = opt.init(u)
    width = jax.tree_util.tree_map(lambda a, b: b - a, lo, hi)
    for _ in range(settings.iterations):
        updates, state_new = opt.update(g, state, u)
        if settings.method == "lbfgs":
            updates = jax.tree_util.tree_map(lambda d: -d, updates)
            slope = sum(float(jnp.vdot(gi, di)) for gi, di in zip(jax.tree_util.tree_leaves(g),
                        jax.tree_util.tree_leaves(updates)))  # fmt: skip
            restart = slope >= 0.0  # curvature pairs across a kink: not a descent direction
            if restart:  # steepest descent, no memory
                updates = jax.tree_util.tree_map(lambda d: -d, g)
                state_new = opt.init(u)
                hist.restarts += 1
            # first / any step: no component moves by more than step_max_fraction of its
            # box (a restart: the largest moves by that much, the line search backtracks)
            most = settings.step_max_fraction
            ratio = max(
                float(jnp.max(jnp.abs(d) / (most * w)))
                for d, w in zip(
                    jax.tree_util.tree_leaves(updates), jax.tree_util.tree_leaves(width)
                )
            )
            if ratio > 1.0 or (restart and ratio > 0.0):
                updates = jax.tree_util.tree_map(lambda d: d / ratio, updates)
        step, accepted = 1.0, False
        for _ in range(settings.max_backtracks + 1):
            trial = project(jax.tree_util.tree_map(lambda a, d: a + step * d, u, updates))
            move = jax.tree_util.tree_map(lambda a, b: a - b, trial, u)
            decrease = float(
                sum(
                    jnp.vdot(gi, mi)
                    for gi, mi in zip(jax.tree_util.tree_leaves(g), jax.tree_util.tree_leaves(move))
                )
            )
            try:
                val_t, g_t = trial_value(trial)
                ok = np.isfinite(val_t) and (
                    settings.method == "adam" or val_t <= val + settings.armijo * decrease
                )
                if ok and g_t is None:  # the accepted trial's gradient, the same design's
                    g_t = evaluate(trial, counted=False)[1]  # run (value: the forward run's)
            except GradientRunError:
                hist.rejected += 1
                step *= 0.5
                continue
            if ok:
                accepted = True
                break
            hist.rejected += 1
            step *= 0.5
        if not accepted:
            hist.stop_reason = "line search found no decrease (stationary within the bounds)"
            break
        u, val, g, state = trial, val_t, g_t, state_new
        record(hist, u, val, g, lo, hi, progress)
    else:
        hist.stop_reason = f"{settings.iterations} iterations"
    return hist


def record(hist, u, val, g, lo, hi, progress):
    gn = _projected_grad_norm(u, g, lo, hi)
    hist.objective.append(val)
    hist.simulations.append(hist.evaluations)
    hist.grad_norm.append(gn)
    hist.designs.append({k: np.asarray(v) for k, v in u.items()})
    if progress is not None:
        progress(len(hist.objective) - 1, val, gn, u)
