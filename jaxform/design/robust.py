"""A design under uncertain inputs: the objective over a few scenarios (each a value of
the uncertain groups, e.g. the friction factor and the die temperature), their mean or
their worst, with its exact gradient.

    DesignProblem / ProcessDesignProblem (design groups + uncertain groups), one per
    scenario --Scenarios(problems, design names, scenarios, aggregate)--> a problem with
          the optimizers' interface over the design groups alone

The uncertain groups are groups of the inner problems like any other; a scenario fixes
their variables (``{group name: u}``), the design leaves them alone.  Scenario k is
evaluated by ``problems[k]`` (the same problem for all, or each its own: a process's plan
made at that scenario's inputs, whose steps its forward run took).  ``worst``: the
largest scenario objective and its gradient (a subgradient where two scenarios tie);
``mean``: the mean of the scenario objectives and of their gradients.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

AGGREGATES = ("mean", "worst")


@dataclass(eq=False)
class Scenarios:
    problems: tuple  # the inner problem of each scenario: every group, design and uncertain
    names: tuple[str, ...]  # the design groups (the optimizer's variables)
    scenarios: tuple[dict, ...]  # each {uncertain group name: u}
    aggregate: str = "worst"

    def __post_init__(self):
        if self.aggregate not in AGGREGATES:
            raise ValueError(f"aggregate {self.aggregate!r}: one of {', '.join(AGGREGATES)}")
        if not self.scenarios or len(self.problems) != len(self.scenarios):
            raise ValueError("a robust design needs one problem per scenario, at least one")

    @property
    def problem(self):
        """The first scenario's problem (the groups, bounds and start of all)."""
        return self.problems[0]

    @property
    def start(self) -> dict:
        return {k: self.problem.start[k] for k in self.names}

    @property
    def groups(self) -> tuple:
        return tuple(g for g in self.problem.groups if g.name in self.names)

    @property
    def first(self):
        """The problem whose groups act on the inputs (a Replanning problem's first)."""
        return getattr(self.problem, "first", self.problem)

    @property
    def plan(self):
        return self.problem.plan

    @property
    def objective(self):
        return self.problem.objective

    @property
    def replans(self) -> int:
        """The inner problems' new plans (Replanning problems'), else 0."""
        return sum(getattr(p, "replans", 0) for p in self.problems)

    def bounds(self):
        lo, hi = self.problem.bounds()
        return {k: lo[k] for k in self.names}, {k: hi[k] for k in self.names}

    def physical(self, design) -> dict:
        out = {}
        for g in self.groups:
            out.update(g.physical(np.asarray(design[g.name])))
        return out

    def _full(self, design, k: int) -> dict:
        return {**design, **self.scenarios[k]}

    def scenario_values(self, design) -> list[float]:
        """The objective in each scenario (one run each): where the problems have forward
        runs (a process's), each scenario's forward run's, as `jaxform run` of the
        design's config with the scenario's inputs gives; else its value."""
        if self._forward_runs():
            return [float(p.forward_value(self._full(design, k)))
                    for k, p in enumerate(self.problems)]  # fmt: skip
        return [float(p.value(self._full(design, k))[0])
                for k, p in enumerate(self.problems)]  # fmt: skip

    def _forward_runs(self) -> bool:
        """Whether every inner problem has a forward run (``forward_value``)."""
        return all(getattr(p, "forward_value", None) for p in self.problems)

    def _aggregate(self, vals) -> float:
        return max(vals) if self.aggregate == "worst" else float(np.mean(vals))

    @property
    def forward_value(self):
        """design -> the objective aggregated over the scenarios' own forward runs, where
        every inner problem has one (a process's, :class:`jaxform.process_design.Replanning`:
        what the optimizers then evaluate trials by); else None."""
        if not self._forward_runs():
            return None
        return lambda design: self._aggregate(self.scenario_values(design))

    def value(self, design):
        runs = [p.value(self._full(design, k)) for k, p in enumerate(self.problems)]
        vals = [float(v) for v, _ in runs]
        if self.aggregate == "mean":
            return float(np.mean(vals)), runs[int(np.argmax(vals))][1]
        k = int(np.argmax(vals))
        return runs[k]

    def value_and_grad(self, design):
        runs = [p.value_and_grad(self._full(design, k)) for k, p in enumerate(self.problems)]
        vals = np.array([float(v) for v, _, _ in runs])
        worst = int(np.argmax(vals))
        if self.aggregate == "worst":
            v, g, traj = runs[worst]
            return v, {k: g[k] for k in self.names}, traj
        grad = {k: sum(g[k] for _, g, _ in runs) / len(runs) for k in self.names}
        return float(vals.mean()), grad, runs[worst][2]

    def report(self, design) -> dict:
        """The inner report in the worst scenario (its terms, forces, constraints), the
        aggregate as ``objective`` and each scenario's objective (``scenario<i>``)."""
        vals = self.scenario_values(design)
        worst = int(np.argmax(vals))
        out = dict(self.problems[worst].report(self._full(design, worst)))
        out["objective"] = self._aggregate(vals)
        constraints = out.pop("constraints", [])
        out.update({f"scenario{k}": v for k, v in enumerate(vals)})
        out["constraints"] = constraints
        return out
