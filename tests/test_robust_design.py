"""A design under uncertain inputs (issue 39, "robust design": jaxform.design.robust,
design.robust of a process).

References: closed forms of a stand-in problem (the mean and the worst of quadratics and
their gradients), the refusal lines of the config check, and, in the slow test, the
process's own runs: the robust objective equals the worst scenario's objective evaluated
alone (1e-12), and the robust design fills the cavity in every scenario.
"""

from __future__ import annotations

import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from cli_harness import assert_refused

from jaxform.design.robust import Scenarios
from jaxform.errors import ConfigError
from jaxform.process_config import check_process_design, load_typed

ROOT = Path(__file__).resolve().parents[1]
TWO_BLOW = ROOT / "experiments" / "two_blow_design.toml"


class _Quadratic:
    """J(x, m) = (x - m)^2 + m: design x, uncertain m (the group 'm')."""

    groups = (SimpleNamespace(name="x", physical=lambda u: {"x": float(u[0])}),
              SimpleNamespace(name="m"))  # fmt: skip
    start = {"x": np.array([0.0]), "m": np.array([0.0])}

    def bounds(self):
        return {"x": np.array([-5.0]), "m": np.array([-5.0])}, {"x": np.array([5.0]),
                                                                 "m": np.array([5.0])}  # fmt: skip

    def value(self, d):
        x, m = float(d["x"][0]), float(d["m"][0])
        return (x - m) ** 2 + m, None

    def value_and_grad(self, d):
        x, m = float(d["x"][0]), float(d["m"][0])
        return (
            (x - m) ** 2 + m,
            {"x": np.array([2 * (x - m)]), "m": np.array([1 - 2 * (x - m)])},
            None,
        )

    def report(self, d):
        return {"objective": self.value(d)[0], "constraints": []}


SCENARIOS = ({"m": np.array([0.0])}, {"m": np.array([1.0])}, {"m": np.array([3.0])})


@pytest.mark.parametrize("aggregate", ["mean", "worst"])
def test_scenarios_aggregate_and_gradient_are_the_closed_forms(aggregate):
    """At x = 1: J = 1, 1, 7 (m = 0, 1, 3); the mean 3 with gradient (2 + 0 - 4) / 3; the
    worst 7 (m = 3) with its gradient -4.  Only the design group is a variable."""
    pb = Scenarios((_Quadratic(),) * 3, ("x",), SCENARIOS, aggregate)
    assert set(pb.start) == {"x"} and set(pb.bounds()[0]) == {"x"}
    val, grad, _ = pb.value_and_grad({"x": np.array([1.0])})
    want = (3.0, -2.0 / 3.0) if aggregate == "mean" else (7.0, -4.0)
    assert abs(val - want[0]) <= 1e-12 and abs(float(grad["x"][0]) - want[1]) <= 1e-12
    assert set(grad) == {"x"}
    assert abs(pb.value({"x": np.array([1.0])})[0] - want[0]) <= 1e-12
    report = pb.report({"x": np.array([1.0])})
    assert [report[f"scenario{k}"] for k in range(3)] == [1.0, 1.0, 7.0]
    assert report["objective"] == want[0]


def test_worst_design_minimizes_the_largest_scenario():
    """min_x max_m (x - m)^2 + m over m in {0, 1, 3}: x* where (x - 0)^2 = (x - 3)^2 + 3,
    i.e. x* = 2 (J = 4), not the nominal m = 0 design x = 0 (J_worst = 12)."""
    from jaxform.design import OptimizerSettings, optimize

    pb = Scenarios((_Quadratic(),) * 3, ("x",), SCENARIOS, "worst")
    hist = optimize(pb, OptimizerSettings("lbfgs", 40))
    best = float(np.asarray(hist.designs[hist.best]["x"])[0])
    assert abs(best - 2.0) <= 1e-3 and abs(hist.objective[hist.best] - 4.0) <= 1e-2


@pytest.mark.parametrize(
    "overrides, needle",
    [
        (["design.robust=worst"], "give the scenarios"),
        (["design.robust=mean", "design.robust_die_temperature_K=[473.0]"], "no coupled heat"),
        (["design.robust=mean", "friction.model=sticking", "design.robust_friction=[0.2]"],
         "no die of a forming operation has a friction coefficient"),
        (["design.robust=median"], "design.robust"),
        (["design.robust=worst", "design.robust_friction=[-0.1]"], "design.robust_friction"),
        (["design.robust=worst", "design.robust_friction=[0.2]",
          "design.operation_variables=['finisher.friction']"], "both designed and uncertain"),
    ],
)  # fmt: skip
def test_bad_robust_design_refused_in_one_line(overrides, needle):
    with pytest.raises(ConfigError, match=needle) as err:
        check_process_design(load_typed(TWO_BLOW, overrides))
    assert "\n" not in str(err.value)


def test_robust_design_of_one_scene_refused(tmp_path):
    """A scene config (no process) with design.robust: one line, exit 2."""
    assert_refused(["design", str(ROOT / "configs" / "preform_design.toml"), "--out",
                    str(tmp_path / "o"), "--set", "design.robust=worst"],
                   "a robust design is a process's so far")  # fmt: skip


@pytest.mark.slow  # the two-blow process's gradient programs (~1 min warm, minutes cold)
def test_robust_process_scenarios_are_the_processes_at_those_inputs():
    """experiments/two_blow_design.toml with design.robust = worst over friction 0.2 and
    0.4: each scenario's objective at the start design equals that of the process
    configured with that friction factor (its own forward run and problem; relative
    1e-9: each scenario replays the plan of its own forward run, to Newton's
    tolerance); the robust value is the larger; its gradient (the worst
    scenario's, in the design groups only) equals central differences of the robust
    objective (h = 1e-4 along a unit direction, relative 1e-4)."""
    from fd_check import directional_derivatives

    from jaxform.process_design import process_problem, robust

    sets = ["design.robust=worst", "design.robust_friction=[0.2, 0.4]"]
    process = load_typed(TWO_BLOW, sets)
    pb = robust(process, process_problem(process))
    assert set(pb.start) == {"billet_volume", "preform.die_spline"}
    values = pb.scenario_values(pb.start)
    for m, got in zip((0.2, 0.4), values):
        alone = load_typed(TWO_BLOW, [f"friction.m={m}"])
        ref = process_problem(alone)
        want = float(ref.value(ref.start)[0])
        assert abs(got - want) <= 1e-9 * abs(want), (m, got, want)
    val, grad, _ = pb.value_and_grad(pb.start)
    assert float(val) == max(values)
    for group in pb.start:
        exact, fd = directional_derivatives(pb, grad, group)
        assert abs(exact - fd) <= 1e-4 * abs(exact), (group, exact, fd)


@pytest.mark.slow  # shares the two-blow process's programs with the test above
def test_a_design_far_from_its_plan_is_evaluated_on_a_new_plan():
    """design.replan_distance = 0.02: a design 1 % of the bound box from the start is
    evaluated on the start's plan (no new plan), one 5 % away on the plan of its own
    forward run (one new plan), whose value is that forward run's objective
    (forward_value, relative 1e-9); the report at a design not evaluated is its forward
    run's (exactly)."""
    import jax.numpy as jnp

    from jaxform.process_design import Replanning, process_problem

    process = load_typed(TWO_BLOW)
    pb = Replanning(process, process_problem(process), replan_distance=0.02)
    lo, hi = pb.bounds()

    def moved(frac):
        return {k: jnp.asarray(v + frac * (hi[k] - lo[k])) if k == "billet_volume" else v
                for k, v in pb.start.items()}  # fmt: skip

    pb.value(moved(-0.01))
    assert pb.replans == 0
    far = moved(-0.05)
    val = float(pb.value(far)[0])
    assert pb.replans == 1
    want = pb.forward_value(far)
    assert abs(val - want) <= 1e-9 * abs(want), (val, want)
    # a design evaluated by no one is reported from its own forward run (exactly), not
    # from a replay on the current plan (made at another design)
    other = moved(-0.03)
    replans = pb.replans
    assert pb.report(other)["objective"] == pb.forward_value(other)
    assert pb.replans == replans


@pytest.mark.slow  # shares the two-blow process's programs with the tests above
def test_a_design_that_starts_a_die_inside_the_part_is_rejected():
    """The billet 22 % larger (billet_volume near its bound): the preform die follows the
    billet's top and ends 0.28 mm higher, above the finisher die's start (z = 3.38 mm at
    the axis): the design's evaluation raises DieIntoPart naming the finisher (as `jaxform
    run` of its config would refuse it), without a new plan; the start passes."""
    import jax.numpy as jnp

    from jaxform.design.process_problem import DieIntoPart
    from jaxform.process_design import Replanning, process_problem

    process = load_typed(TWO_BLOW)
    pb = Replanning(process, process_problem(process))
    pb.value(pb.start)
    big = dict(pb.start, billet_volume=jnp.asarray([0.2]))
    with pytest.raises(DieIntoPart, match=r"operation\[2\] \(finisher\)"):
        pb.value(big)
    assert pb.replans == 0


def test_scenarios_set_each_forming_operations_friction_and_die_temperature():
    """On the tiny coupled process (test_designed_config's): the uncertain groups are each
    forming operation's friction and die temperature; a scenario of m = 0.25 and 523 K
    sets every coefficient to 0.25 and every die temperature to 523 K in the inputs the
    problem runs (1e-12), and the grid of 2 x 2 values gives 4 scenarios."""
    import jax.numpy as jnp

    from jaxform.design.process_problem import (
        build_process_problem,
        scenario_designs,
        uncertain_groups,
        with_groups,
    )

    sys.path.insert(0, str(Path(__file__).parent))
    from test_designed_config import problem as coupled

    _, designed = coupled()
    pb = build_process_problem(designed.plan, ("billet",), designed.objective)
    extra = uncertain_groups(pb.plan, True, True)
    names = {g.name for g in extra}
    assert names == {"first.friction", "first.die_temperature", "second.friction",
                     "second.die_temperature"}  # fmt: skip
    assert len(scenario_designs(extra, (0.2, 0.4), (473.0, 523.0))) == 4
    (scenario,) = scenario_designs(extra, (0.25,), (523.0,))
    full = with_groups(pb, extra)
    design = {**full.start, **{k: jnp.asarray(v) for k, v in scenario.items()}}
    for k, stage in enumerate(full.plan.stages):
        if not stage.operation.forming:
            continue
        inputs, _ = full.on_stage(design, k, stage.scene.inputs, jnp.ones(1))
        assert abs(float(inputs.thermal.die_temperature_K) - 523.0) <= 1e-12
        for die in inputs.die.members:
            assert abs(float(die.friction.m) - 0.25) <= 1e-12
