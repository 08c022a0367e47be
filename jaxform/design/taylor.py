"""Taylor test of a design problem's gradient (in the spirit of pyadjoint's taylor_test).

For a design u, a direction du and steps h_0 > h_1 > ... (halving):

    R0(h) = |J(u + h du) - J(u)|                  -> 0 like h   (rate 1)
    R1(h) = |J(u + h du) - J(u) - h dJ(u).du|     -> 0 like h^2 (rate 2 iff dJ is right)

rate_k = log(R(h_{k-1}) / R(h_k)) / log(h_{k-1} / h_k).  Each design group is tested
on its own (the direction is zero in the other groups), so a wrong derivative in one
group cannot hide behind another's.  The direction is random (seeded) with a per-group
scale; each group's direction comes from its own generator, seeded by ``seed`` and the
group's name, so adding a group does not change the others' directions.

The test finds its window.  A run is differentiable only on one contact active set (each
candidate open, sticking or slipping at each step): a perturbed run whose active set
differs from the unperturbed one's, or that does not converge, crosses a kink, where R1
falls like h, not h^2, although the gradient is right.  Such an h is skipped and the
steps go on halving (up to ``max_halvings`` beyond the given ones) until ``len(h)``
consecutive steps stay on the active set.  Where J is nearly linear in h, its h^3 terms
can rival the h^2 term over the first steps (seed scene, die group: J(h) = J0 + 16.6 h
- 0.030 h^2 + 0.038 h^3); while the window's rates fall short of ``rate_target``, it
moves down a halving (a wrong gradient stays at rate 1 all the way down and fails).
Going down, a remainder R1 below the noise floor of the runs (``noise`` x |J|: Newton
converges to a tolerance, not exactly) ends the window there; rates are taken only
between remainders above it, and a group whose R1 is below it already at the first step
in the window agrees with finite differences to the noise (reported as such, and
passing).  A base run that sits on a kink itself (a node at its stick/slip threshold, to
round-off) changes its active set for every step along du however small; the window is
then sought along -du, the side where J is smooth.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from jaxform.gradients import GradientRunError

# magnitude of the random direction per group, in that group's design variables
SCALE = {
    "material": 0.02,
    "friction": 0.01,
    "speed": 0.02,
    "preform": 0.01,
    "nodes": 0.003,
    "die": 0.01,
    "die_spline": 0.01,
    "thermal": 0.01,
    "billet": 0.01,
    "billet_volume": 0.01,
    "dwell": 0.02,
}
# groups that move the geometry (mm): their direction is also capped at this fraction of
# the run's stroke, so that a scene pressed by a few micrometres (Prandtl's punch: 1.8 um)
# is not tested with a die lifted off the material or elements larger than its motion
GEOMETRIC = ("nodes", "die", "die_spline", "preform", "billet", "billet_volume")
STROKE_FRACTION = 0.05


@dataclass(frozen=True)
class TaylorRow:
    group: str
    h: np.ndarray
    r0: np.ndarray
    r1: np.ndarray
    rate0: np.ndarray  # (len(h) - 1,)
    rate1: np.ndarray
    dj_du: float  # directional derivative dJ.du
    floor: float = 0.0  # noise floor of the remainders (below it a rate means nothing)
    skipped: tuple = field(default_factory=tuple)  # h left out: another active set, or no run
    sign: float = 1.0  # -1: the window is along -du (the base run sits on a kink along +du)

    @property
    def measured(self) -> np.ndarray:
        """Which rates compare two remainders above the noise floor."""
        above = self.r1 > self.floor
        return above[:-1] & above[1:]

    @property
    def min_rate(self) -> float:
        """The smallest second-order rate measured; inf where the window ended at the noise
        floor before two remainders above it could be compared (the gradient agrees with
        finite differences to the noise); 0 where no window was found (nothing checked)."""
        rates = self.rate1[self.measured]
        if len(rates):
            return float(np.min(rates))
        at_floor = len(self.r1) > 0 and self.r1[-1] <= self.floor
        return float("inf") if at_floor else 0.0


@dataclass(frozen=True)
class Window:
    """How the Taylor test seeks its window of steps."""

    max_halvings: int = 10  # how many halvings past the last given step it may go
    noise: float = 1e-9  # relative noise floor of J: remainders below noise x |J| are noise
    # the second-order rate a window must show; below it (and above the noise floor) the
    # window moves down by a halving while steps are left
    rate_target: float = 1.9


def _rates(h, r):
    r = np.maximum(r, 1e-300)
    return np.log(r[:-1] / r[1:]) / np.log(h[:-1] / h[1:])


def _window(problem, design, name, du, dj, steps, base, progress):
    """(h, J, skipped) of the window: consecutive steps whose runs stay on the base run's
    active set (``base``: j0, status0, floor, wanted length, rate target), moved down
    while its rates are below the target and its remainders above the noise floor (the
    remainder is not yet in its asymptotic range: its h^3 terms still count)."""
    j0, status0, floor, wanted, target = base
    hs, js, skipped = [], [], []
    for hk in steps:
        if len(hs) == wanted:
            h_w, r1 = np.array(hs), np.abs(np.array(js) - j0 - np.array(hs) * dj)
            if np.min(_rates(h_w, r1)) >= target:
                break
            hs, js = hs[1:], js[1:]  # slide down by one step
        pert = dict(design)
        pert[name] = design[name] + hk * du
        try:
            jk, traj = problem.value(pert)
            same = np.array_equal(np.asarray(traj.contact_status), status0)
        except GradientRunError:
            jk, same = float("nan"), False
        if progress is not None:
            progress(name, hk, float(jk))
        if not same:  # a kink between u and u + h du: smaller steps, a new window
            skipped.append(hk)
            hs, js = [], []
            continue
        hs.append(hk)
        js.append(float(jk))
        if abs(js[-1] - j0 - hk * dj) <= floor:  # smaller steps would measure noise
            break
    return np.array(hs), np.array(js), tuple(skipped)


def taylor_test(
    problem,
    design=None,
    h=(1.0, 0.5, 0.25, 0.125),
    seed=0,
    groups: tuple[str, ...] | None = None,
    progress=None,
    window: Window = Window(),
) -> list[TaylorRow]:
    """Taylor remainders for each group of ``problem`` at ``design`` (a gradient check).

    Arguments:
        problem: a :class:`jaxform.design.problem.DesignProblem`.
        design: where to test (default ``problem.start``).
        h: decreasing multiples of a random direction (seeded by ``seed`` and the group):
            the first steps tried and the length of the window.
        groups: the group names to test (default all of the problem's).
        progress: called with (group, h, J) after each evaluation.
        window: how the window is sought (:class:`Window`).

    Returns:
        one :class:`TaylorRow` per group: the window's steps, remainders
        |J(u+h du)-J(u)| (rate 1) and |J(u+h du)-J(u)-h dJ.du| (rate 2 when the gradient
        is right), their rates, the noise floor and the steps skipped.
    """
    design = problem.start if design is None else design
    design = {k: np.asarray(v, dtype=float) for k, v in design.items()}
    j0, grad, traj0 = problem.value_and_grad(design)
    j0 = float(j0)
    strokes = getattr(traj0, "stroke_mm", None)  # None: a problem without a ram
    stroke = np.inf if strokes is None else float(np.max(np.abs(np.asarray(strokes))))
    floor = window.noise * max(abs(j0), 1e-300)
    base = (j0, np.asarray(traj0.contact_status), floor, len(h), window.rate_target)
    h = np.asarray(h, dtype=float)
    steps = [*h, *(h[-1] * 0.5 ** np.arange(1, window.max_halvings + 1))]
    rows = []
    for g in problem.groups:
        if groups is not None and g.name not in groups:
            continue
        rng = np.random.default_rng([seed, *g.name.encode()])
        kind = getattr(g, "kind", g.name)  # a process's group: <operation>.<kind>
        scale = SCALE.get(kind, 0.01)
        if kind in GEOMETRIC:
            scale = min(scale, STROKE_FRACTION * stroke)
        du = scale * rng.standard_normal(design[g.name].shape)
        dj = float(np.dot(np.asarray(grad[g.name]).ravel(), du.ravel()))
        hs, js, skipped = _window(problem, design, g.name, du, dj, steps, base, progress)
        sign = 1.0
        if len(hs) < 2:  # the base run sits on a kink: try the side it is smooth on
            hs2, js2, skipped2 = _window(problem, design, g.name, -du, -dj, steps, base, progress)
            if len(hs2) > len(hs):
                hs, js, skipped, sign = hs2, js2, skipped + skipped2, -1.0
        r0, r1 = np.abs(js - j0), np.abs(js - j0 - hs * sign * dj)
        rows.append(TaylorRow(g.name, hs, r0, r1, _rates(hs, r0), _rates(hs, r1), sign * dj,
                              base[2], skipped, sign))  # fmt: skip
    return rows


def format_table(rows: list[TaylorRow]) -> str:
    """The remainders and rates of each group's window, the steps skipped and the noise
    floor; a rate between remainders at the noise floor is shown as 'noise'."""
    lines = [
        f"{'group':<10} {'h':>9} {'|J(u+h du)-J(u)|':>18} {'rate':>6} "
        f"{'|...-h dJ.du|':>14} {'rate':>6}"
    ]
    for row in rows:
        for k, hk in enumerate(row.h):
            ra0 = f"{row.rate0[k - 1]:6.2f}" if k else " " * 6
            ra1 = " " * 6
            if k:
                ra1 = f"{row.rate1[k - 1]:6.2f}" if row.measured[k - 1] else " noise"
            lines.append(
                f"{row.group:<10} {hk:9.4g} {row.r0[k]:18.6e} {ra0} {row.r1[k]:14.6e} {ra1}"
            )
        window = f"window h = {row.h[0]:g} .. {row.h[-1]:g}" if len(row.h) else "no window"
        window += " along -du" if row.sign < 0 else ""
        skipped = ", ".join(f"{v:g}" for v in row.skipped) or "none"
        lines.append(
            f"{row.group:<10} {window}; skipped (another active set or no run): {skipped}; "
            f"noise floor {row.floor:.2e}"
        )
    return "\n".join(lines)
