"""Sampling optimizers, as the commercial forging codes design: no gradients, one run per
trial design (``problem.value``), within the problem's box bounds.

* :class:`LhsRsm`  a Latin hypercube of ``samples_per_variable`` runs per design variable
  (seeded), a quadratic response surface fitted by least squares (the full quadratic
  where the runs that succeeded number at least its coefficients, 1 + n + n(n+1)/2 for
  n variables; else the diagonal one, without cross terms), its minimum within the bounds
  (the stationary point where the surface is convex and it lies inside; else a bounded
  quasi-Newton search from several starts), that minimum verified by one more run;
  ``rounds`` > 1 refits with the verified runs added and verifies again.
* :class:`CmaEs`   CMA-ES, the (mu/mu_w, lambda) evolution strategy with cumulative
  step-size adaptation and rank-one plus rank-mu covariance updates (Hansen's tutorial,
  arXiv:1604.00772, its default parameters), in the box scaled to [0, 1] per variable.
  A sample outside the box is run at its projection onto it; its fitness adds the
  generation's range of objective values times its squared distance to the box, so that
  it ranks behind an equal sample inside; the mean is kept inside the box.

Both return the :class:`jaxform.design.optimizers.DesignHistory` with one row per run:
its design, its objective (NaN where the run failed) and the runs used so far.  A run
that fails (:class:`GradientRunError`) counts as a run and is left out of the fit (LHS)
or ranked last (CMA-ES).  Pure NumPy/SciPy on the host: the problem owns the compiled
programs.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from jaxform import program_store
from jaxform.design.optimizers import DesignHistory
from jaxform.gradients import GradientRunError


@dataclass(frozen=True)
class Box:
    """The design dict <-> a flat vector, and the bounds as vectors."""

    keys: tuple[str, ...]
    sizes: tuple[int, ...]
    lo: np.ndarray
    hi: np.ndarray

    @staticmethod
    def of(problem) -> Box:
        lo, hi = problem.bounds()
        keys = tuple(problem.start)
        sizes = tuple(int(np.size(problem.start[k])) for k in keys)
        flat = [np.concatenate([np.ravel(np.asarray(b[k], dtype=float)) for k in keys])
                for b in (lo, hi)]  # fmt: skip
        return Box(keys, sizes, flat[0], flat[1])

    def flat(self, design: dict) -> np.ndarray:
        return np.concatenate([np.ravel(np.asarray(design[k], dtype=float)) for k in self.keys])

    def tree(self, x: np.ndarray) -> dict:
        cuts = np.cumsum(self.sizes)[:-1]
        return {k: np.asarray(v) for k, v in zip(self.keys, np.split(np.asarray(x), cuts))}

    def to_unit(self, x):
        return (np.asarray(x) - self.lo) / (self.hi - self.lo)

    def from_unit(self, y):
        return self.lo + np.asarray(y) * (self.hi - self.lo)


class _Runs:
    """Runs trial designs, records them in the history, reports progress.  A problem with
    a ``forward_value`` (a process's: :class:`jaxform.process_design.Replanning`) is
    evaluated by the forward simulation at each design, as the sampling codes run it;
    another by its ``value``."""

    def __init__(self, problem, box: Box, progress, history=None):
        self.problem, self.box, self.progress = problem, box, progress
        self.hist = DesignHistory() if history is None else history
        self.best = np.inf

    def _value(self, design) -> float:
        forward = getattr(self.problem, "forward_value", None)
        if forward is not None:
            return float(forward(design))
        return float(self.problem.value(design)[0])

    def __call__(self, x: np.ndarray) -> float:
        design = self.box.tree(np.clip(x, self.box.lo, self.box.hi))
        program_store.make_room()  # each design's meshes compile programs of their own
        try:
            val = self._value(design)
        except GradientRunError:
            val = np.nan
        h = self.hist
        h.evaluations += 1
        h.rejected += int(not np.isfinite(val))
        h.objective.append(val)
        h.grad_norm.append(np.nan)
        h.designs.append(design)
        h.simulations.append(h.evaluations)
        if np.isfinite(val):
            self.best = min(self.best, val)
        if self.progress is not None:
            self.progress(h.evaluations, val, self.best, design)
        return val


def latin_hypercube(n: int, d: int, rng: np.random.Generator) -> np.ndarray:
    """(n, d) points in [0, 1)^d: each variable's n values in the n strata of [0, 1), one
    each, randomly paired across variables."""
    strata = np.stack([rng.permutation(n) for _ in range(d)], axis=1)
    return (strata + rng.random((n, d))) / n


def quadratic_features(s: np.ndarray, full: bool) -> np.ndarray:
    """(n, p) features of the response surface at scaled points s (n, d): 1, s_i and
    s_i s_j (i <= j) for the full quadratic, 1, s_i, s_i^2 for the diagonal one."""
    n, d = s.shape
    cols = [np.ones((n, 1)), s]
    if full:
        i, j = np.triu_indices(d)
        cols.append(s[:, i] * s[:, j])
    else:
        cols.append(s**2)
    return np.concatenate(cols, axis=1)


def n_coefficients(d: int, full: bool) -> int:
    return 1 + d + (d * (d + 1) // 2 if full else d)


@dataclass(frozen=True)
class Quadratic:
    """q(s) = c + g.s + s.H s / 2 in the scaled variables s in [-1, 1]^d."""

    c: float
    g: np.ndarray
    h: np.ndarray

    @staticmethod
    def fit(s: np.ndarray, f: np.ndarray, full: bool) -> Quadratic:
        coef = np.linalg.lstsq(quadratic_features(s, full), f, rcond=None)[0]
        d = s.shape[1]
        h = np.zeros((d, d))
        if full:
            i, j = np.triu_indices(d)
            h[i, j] += coef[1 + d :]
            h[j, i] += coef[1 + d :]  # the diagonal twice: d^2/ds_i^2 of a s_i^2 is 2a
        else:
            h[np.diag_indices(d)] = 2.0 * coef[1 + d :]
        return Quadratic(float(coef[0]), coef[1 : 1 + d], h)

    def __call__(self, s):
        return self.c + self.g @ s + 0.5 * s @ self.h @ s

    def grad(self, s):
        return self.g + self.h @ s

    def minimum(self, starts: np.ndarray) -> np.ndarray:
        """The minimizer within [-1, 1]^d: the stationary point where the Hessian is
        positive definite and the point lies inside; else the best of bounded
        quasi-Newton searches (L-BFGS-B) from ``starts``."""
        d = len(self.g)
        try:
            eig = np.linalg.eigvalsh(self.h)
            if eig.min() > 1e-12 * max(1.0, eig.max()):
                s = np.linalg.solve(self.h, -self.g)
                if np.all(np.abs(s) <= 1.0):
                    return s
        except np.linalg.LinAlgError:
            pass
        best, best_q = np.zeros(d), np.inf
        for s0 in starts:
            opts = dict(ftol=1e-15, gtol=1e-12)
            r = minimize(self, np.clip(s0, -1.0, 1.0), jac=self.grad, method="L-BFGS-B",
                         bounds=[(-1.0, 1.0)] * d, options=opts)  # fmt: skip
            if r.fun < best_q:
                best, best_q = r.x, float(r.fun)
        return best


@dataclass(frozen=True)
class LhsRsm:
    """Latin hypercube + quadratic response surface (module docstring).

    Arguments:
        samples_per_variable: LHS runs per design variable (8 as DEGREE's optimizer).
        rounds: fit-minimize-verify rounds (1: one verification run).
        max_simulations: the most runs in all (the hypercube is cut to leave the rounds).
        seed: the hypercube's random seed."""

    samples_per_variable: int = 8
    rounds: int = 1
    max_simulations: int = 200
    seed: int = 0

    def minimize(self, problem, design=None, progress: Callable | None = None,
                 history=None) -> DesignHistory:  # fmt: skip
        """Run the plan on ``problem`` (``design`` is not used: a plan has no start);
        ``progress`` is called after each run with (runs, objective, best, design)."""
        box = Box.of(problem)
        run = _Runs(problem, box, progress, history)
        rng = np.random.default_rng(self.seed)
        d = len(box.lo)
        rounds = min(self.rounds, max(self.max_simulations - 1, 1))
        n0 = max(1, min(self.samples_per_variable * d, self.max_simulations - rounds))
        ys = latin_hypercube(n0, d, rng)
        xs = [box.from_unit(y) for y in ys]
        fs = [run(x) for x in xs]
        for _ in range(rounds):
            ok = np.isfinite(fs)
            if ok.sum() < 2:
                run.hist.stop_reason = "fewer than 2 runs succeeded: no response surface"
                return run.hist
            s = 2.0 * box.to_unit(np.asarray(xs)[ok]) - 1.0
            full = ok.sum() >= n_coefficients(d, True)
            q = Quadratic.fit(s, np.asarray(fs)[ok], full)
            order = np.argsort(np.asarray(fs)[ok])
            starts = np.vstack([s[order[:3]], np.zeros((1, d)), 2.0 * rng.random((4, d)) - 1.0])
            x = box.from_unit(0.5 * (q.minimum(starts) + 1.0))
            xs.append(x)
            fs.append(run(x))
        kind = "full" if full else "diagonal"
        run.hist.stop_reason = (f"{n0} Latin hypercube runs, {kind} quadratic surface, "
                                f"{rounds} verification run(s)")  # fmt: skip
        return run.hist


@dataclass(frozen=True)
class CmaEs:
    """CMA-ES (module docstring).

    Arguments:
        population: runs per generation lambda (0: 4 + floor(3 ln n)).
        sigma: the initial step size, a fraction of each variable's box.
        max_simulations: the most runs in all.
        seed: the sampling's random seed.
        tol: stop when the step size times the largest axis of the search distribution is
            below this (box units)."""

    population: int = 0
    sigma: float = 0.3
    max_simulations: int = 200
    seed: int = 0
    tol: float = 1e-12

    def minimize(self, problem, design=None, progress: Callable | None = None,
                 history=None) -> DesignHistory:  # fmt: skip
        """Minimize from ``design`` (default ``problem.start``); ``progress`` is called
        after each run with (runs, objective, best, design)."""
        box = Box.of(problem)
        run = _Runs(problem, box, progress, history)
        rng = np.random.default_rng(self.seed)
        start = box.flat(problem.start if design is None else design)
        state = _CmaState.start(np.clip(box.to_unit(start), 0.0, 1.0), self.sigma, self.population)
        while True:
            lam = state.lam
            if run.hist.evaluations + lam > self.max_simulations:
                run.hist.stop_reason = f"{self.max_simulations} runs (the budget)"
                break
            y = state.sample(rng)
            inside = np.clip(y, 0.0, 1.0)
            f = np.array([run(box.from_unit(p)) for p in inside])
            finite = f[np.isfinite(f)]
            spread = float(np.ptp(finite)) if len(finite) > 1 else 1.0
            fitness = np.where(np.isfinite(f), f, np.inf)
            fitness = fitness + max(spread, 1e-300) * np.sum((y - inside) ** 2, axis=1)
            state = state.update(y, np.argsort(fitness, kind="stable"))
            if state.sigma * np.sqrt(np.max(state.eig)) < self.tol:
                run.hist.stop_reason = "step size below the tolerance (converged)"
                break
        return run.hist


@dataclass(frozen=True)
class _CmaState:
    """One generation's search distribution N(m, sigma^2 C) and evolution paths."""

    mean: np.ndarray
    sigma: float
    cov: np.ndarray
    pc: np.ndarray
    ps: np.ndarray
    lam: int
    eig: np.ndarray  # eigenvalues of C
    basis: np.ndarray  # its eigenvectors (columns)
    generation: int = 0

    @staticmethod
    def start(mean: np.ndarray, sigma: float, population: int) -> _CmaState:
        n = len(mean)
        lam = population if population > 0 else 4 + int(3 * np.log(n))
        z = np.zeros(n)
        return _CmaState(mean, sigma, np.eye(n), z, z, max(lam, 2), np.ones(n), np.eye(n))

    def weights(self):
        mu = self.lam // 2
        w = np.log(mu + 0.5) - np.log(np.arange(1, mu + 1))
        w = w / w.sum()
        return w, 1.0 / np.sum(w**2)

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        z = rng.standard_normal((self.lam, len(self.mean)))
        return self.mean + self.sigma * (z * np.sqrt(self.eig)) @ self.basis.T

    def update(self, y: np.ndarray, order: np.ndarray) -> _CmaState:
        n = len(self.mean)
        w, mueff = self.weights()
        cc = (4 + mueff / n) / (n + 4 + 2 * mueff / n)
        cs = (mueff + 2) / (n + mueff + 5)
        c1 = 2 / ((n + 1.3) ** 2 + mueff)
        cmu = min(1 - c1, 2 * (mueff - 2 + 1 / mueff) / ((n + 2) ** 2 + mueff))
        damps = 1 + 2 * max(0.0, np.sqrt((mueff - 1) / (n + 1)) - 1) + cs
        chi_n = np.sqrt(n) * (1 - 1 / (4 * n) + 1 / (21 * n**2))
        steps = (y[order[: len(w)]] - self.mean) / self.sigma  # (mu, n)
        step = w @ steps
        mean = np.clip(self.mean + self.sigma * step, 0.0, 1.0)
        inv_sqrt = self.basis @ np.diag(1 / np.sqrt(self.eig)) @ self.basis.T
        ps = (1 - cs) * self.ps + np.sqrt(cs * (2 - cs) * mueff) * inv_sqrt @ step
        gen = self.generation + 1
        norm = np.linalg.norm(ps) / np.sqrt(1 - (1 - cs) ** (2 * gen))
        hsig = float(norm < (1.4 + 2 / (n + 1)) * chi_n)
        pc = (1 - cc) * self.pc + hsig * np.sqrt(cc * (2 - cc) * mueff) * step
        rank_mu = (steps * w[:, None]).T @ steps
        cov = ((1 - c1 - cmu) * self.cov + c1 * (np.outer(pc, pc) + (1 - hsig) * cc * (2 - cc)
               * self.cov) + cmu * rank_mu)  # fmt: skip
        cov = 0.5 * (cov + cov.T)
        sigma = self.sigma * np.exp((cs / damps) * (np.linalg.norm(ps) / chi_n - 1))
        eig, basis = np.linalg.eigh(cov)
        eig = np.maximum(eig, 1e-30)
        return _CmaState(mean, float(sigma), cov, pc, ps, self.lam, eig, basis, gen)
