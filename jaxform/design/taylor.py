"""Taylor test of a design problem's gradient (in the spirit of pyadjoint's taylor_test).

For a design u, a direction du and steps h_0 > h_1 > ... (halving):

    R0(h) = |J(u + h du) - J(u)|                  -> 0 like h   (rate 1)
    R1(h) = |J(u + h du) - J(u) - h dJ(u).du|     -> 0 like h^2 (rate 2 iff dJ is right)

rate_k = log(R(h_{k-1}) / R(h_k)) / log(h_{k-1} / h_k).  Each design group is tested
on its own (the direction is zero in the other groups), so a wrong derivative in one
group cannot hide behind another's.  The direction is random (seeded) with a per-group
scale small enough to stay on one contact active set and large enough to rise above the
Newton tolerance.  Each group's direction comes from its own generator, seeded by
``seed`` and the group's name, so adding a group does not change the others' directions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# magnitude of the random direction per group, in that group's design variables
SCALE = {
    "material": 0.02,
    "friction": 0.01,
    "speed": 0.02,
    "preform": 0.01,
    "nodes": 0.003,
    "die": 0.01,
}


@dataclass(frozen=True)
class TaylorRow:
    group: str
    h: np.ndarray
    r0: np.ndarray
    r1: np.ndarray
    rate0: np.ndarray  # (len(h) - 1,)
    rate1: np.ndarray
    dj_du: float  # directional derivative dJ.du

    @property
    def min_rate(self) -> float:
        return float(np.min(self.rate1))


def _rates(h, r):
    r = np.maximum(r, 1e-300)
    return np.log(r[:-1] / r[1:]) / np.log(h[:-1] / h[1:])


def taylor_test(
    problem,
    design=None,
    h=(1.0, 0.5, 0.25, 0.125),
    seed=0,
    groups: tuple[str, ...] | None = None,
    progress=None,
) -> list[TaylorRow]:
    """Taylor remainders for each group of ``problem`` at ``design`` (a gradient check).

    Arguments:
        problem: a :class:`jaxform.design.problem.DesignProblem`.
        design: where to test (default ``problem.start``).
        h: decreasing multiples of a random direction (seeded by ``seed`` and the group).
        groups: the group names to test (default all of the problem's).
        progress: called with (group, h, J) after each evaluation.

    Returns:
        one :class:`TaylorRow` per group: remainders |J(u+h du)-J(u)| (rate 1) and
        |J(u+h du)-J(u)-h dJ.du| (rate 2 when the gradient is right) and their rates.
    """
    design = problem.start if design is None else design
    design = {k: np.asarray(v, dtype=float) for k, v in design.items()}
    j0, grad, _ = problem.value_and_grad(design)
    j0 = float(j0)
    h = np.asarray(h, dtype=float)
    rows = []
    for g in problem.groups:
        if groups is not None and g.name not in groups:
            continue
        rng = np.random.default_rng([seed, *g.name.encode()])
        du = SCALE.get(g.name, 0.01) * rng.standard_normal(design[g.name].shape)
        dj = float(np.dot(np.asarray(grad[g.name]).ravel(), du.ravel()))
        r0, r1 = [], []
        for hk in h:
            pert = dict(design)
            pert[g.name] = design[g.name] + hk * du
            jk = float(problem.value(pert)[0])
            r0.append(abs(jk - j0))
            r1.append(abs(jk - j0 - hk * dj))
            if progress is not None:
                progress(g.name, hk, jk)
        r0, r1 = np.array(r0), np.array(r1)
        rows.append(TaylorRow(g.name, h, r0, r1, _rates(h, r0), _rates(h, r1), dj))
    return rows


def format_table(rows: list[TaylorRow]) -> str:
    lines = [
        f"{'group':<10} {'h':>9} {'|J(u+h du)-J(u)|':>18} {'rate':>6} "
        f"{'|...-h dJ.du|':>14} {'rate':>6}"
    ]
    for row in rows:
        for k, hk in enumerate(row.h):
            ra0 = f"{row.rate0[k - 1]:6.2f}" if k else " " * 6
            ra1 = f"{row.rate1[k - 1]:6.2f}" if k else " " * 6
            lines.append(
                f"{row.group:<10} {hk:9.4g} {row.r0[k]:18.6e} {ra0} {row.r1[k]:14.6e} {ra1}"
            )
    return "\n".join(lines)
