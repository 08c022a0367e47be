"""A process design's evaluations are each a full gradient run of the process (minutes on
the two-stage disk): :class:`jaxform.process_design.Replanning` keeps the first one and
the best so far, so that the design report at the start and at the best design, and a
second evaluation of either, run nothing.  Reference: a counting stand-in for the
process problem (its value is the square of its one variable)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from jaxform.design import OptimizerSettings, optimize
from jaxform.process_design import Replanning


class Counting:
    """A process problem's interface, f(a) = (a - 0.3)^2 on [-1, 1], runs counted."""

    start = {"a": np.array([1.0])}
    runs = 0

    def bounds(self):
        return {"a": np.array([-1.0])}, {"a": np.array([1.0])}

    def physical(self, design):
        return {"a": float(np.asarray(design["a"])[0])}

    def value_and_grad(self, design):
        self.runs += 1
        a = np.asarray(design["a"], np.float64)
        return float(np.sum((a - 0.3) ** 2)), {"a": 2.0 * (a - 0.3)}, f"run {self.runs}"

    def value(self, design):
        val, _, traj = self.value_and_grad(design)
        return val, traj

    def report(self, design, evaluated=None):
        val, _, traj = self.value_and_grad(design) if evaluated is None else evaluated
        return {"objective": val, "run": traj}

    def check_dies_clear(self, design, traj):
        pass


def replanning():
    """Replanning over the stand-in, whose forward runs (``forward_value``) are counted in
    ``inner.forward`` and kept as the real ones are."""
    process = SimpleNamespace(operations=[SimpleNamespace(config=SimpleNamespace(design=None))])
    inner = Counting()
    inner.forward = 0
    pb = Replanning(process, inner)

    def forward_run(design):
        inner.forward += 1
        a = np.asarray(design["a"], np.float64)
        return inner, (float(np.sum((a - 0.3) ** 2)), None, f"forward {inner.forward}")

    pb._forward_run = forward_run
    return pb, inner


def test_the_reports_at_the_start_and_the_best_design_run_nothing():
    """After an L-BFGS design of 3 iterations: the report and the value at the start and
    at the best design come from the runs the optimizer made (no further run, the same
    run's output); a design evaluated neither first nor best is reported from its own
    forward run (what `jaxform run` of its config gives), not a replay on a plan made at
    another design."""
    pb, inner = replanning()
    hist = optimize(pb, OptimizerSettings("lbfgs", iterations=3))
    runs = inner.runs
    assert inner.forward + 1 == hist.evaluations and runs >= 4  # the start's run, then trials
    start, best = hist.designs[0], hist.designs[hist.best]
    assert hist.best > 0 and hist.objective[hist.best] < hist.objective[0]
    assert pb.report(start) == {"objective": hist.objective[0], "run": "run 1"}
    assert pb.report(best)["objective"] == hist.objective[hist.best]
    assert pb.value(best)[0] == hist.objective[hist.best]
    assert inner.runs == runs  # nothing ran
    forward = inner.forward
    report = pb.report({"a": np.array([-0.5])})
    assert report == {"objective": pytest.approx(0.64, rel=1e-12), "run": f"forward {forward + 1}"}
    assert (inner.runs, inner.forward) == (runs, forward + 1)


def test_the_kept_best_follows_the_least_objective_and_skips_failed_runs():
    """Only the first evaluation and the least one are kept (a later worse one replaces
    nothing; a better one replaces the best)."""
    pb, inner = replanning()
    for a in (1.0, 0.5, 0.8, 0.35):
        pb.value_and_grad({"a": np.array([a])})
    roles = sorted(role for _, _, role in pb.kept.values())
    assert roles == ["best", "first"] and len(pb.kept) == 2
    assert pb.report({"a": np.array([0.35])})["run"] == "run 4"
    assert pb.report({"a": np.array([1.0])})["run"] == "run 1"
    assert pb.report({"a": np.array([0.5])})["run"] == "forward 1"  # no longer kept: runs
    assert inner.runs == 4


def test_a_value_run_is_kept_and_a_gradient_run_there_replaces_it():
    """A sampling optimizer evaluates values only: the first and the least are kept as
    well (a report there runs nothing); a gradient asked at a design kept without one
    runs once and is then kept in its place."""
    pb, inner = replanning()
    for a in (1.0, 0.2, 0.6):
        pb.value({"a": np.array([a])})
    assert inner.runs == 3
    assert pb.report({"a": np.array([0.2])})["run"] == "run 2"
    assert inner.runs == 3
    val, grad, run = pb.value_and_grad({"a": np.array([0.2])})
    assert inner.runs == 4 and run == "run 4" and float(grad["a"][0]) == pytest.approx(-0.2)
    assert pb.value_and_grad({"a": np.array([0.2])})[2] == "run 4"
    assert inner.runs == 4


def test_a_sampling_optimizer_runs_the_forward_process_not_the_replay():
    """LHS-RSM on a process problem evaluates each design by its forward run
    (``forward_value``: one simulation a design, as the sampling codes run them), never by
    a replay of a plan; the history holds those values."""
    from jaxform.design import LhsRsm

    pb, inner = replanning()
    hist = optimize(pb, LhsRsm(samples_per_variable=4, rounds=1, max_simulations=10, seed=0))
    assert inner.runs == 0 and inner.forward == hist.evaluations >= 4
    a = np.array([float(d["a"][0]) for d in hist.designs])
    np.testing.assert_allclose(hist.objective, (a - 0.3) ** 2)


def test_lbfgs_on_a_process_runs_a_gradient_only_where_a_trial_is_accepted():
    """L-BFGS on a process problem: each line-search trial is its forward run, the
    gradient (a replay, or a new plan) is evaluated at the start and at each accepted
    trial only; the values recorded are the forward runs' (equal to the replay's here);
    each design run counts one simulation, with its gradient or without."""
    pb, inner = replanning()
    hist = optimize(pb, OptimizerSettings("lbfgs", iterations=3))
    accepted = len(hist.objective) - 1
    assert inner.runs == 1 + accepted  # the start, then one per accepted step
    assert inner.forward == accepted + hist.rejected >= accepted
    assert hist.evaluations == 1 + inner.forward
    assert hist.objective[-1] < hist.objective[0]


@pytest.mark.parametrize("fraction", [0.25, 0.05])
def test_no_lbfgs_step_moves_a_variable_more_than_its_share_of_the_box(fraction):
    """design.step_max_fraction: on (a - 0.3)^2 over [-1, 1] from a = 1 (the minimum 0.7
    away, the box 2 wide), each accepted step moves a by at most fraction x 2 (1e-12),
    and the first by exactly that (the gradient's step, 1.4, is larger); with 0.05 the
    design needs at least 7 steps to reach the minimum, with 0.25 two."""
    pb, _ = replanning()
    hist = optimize(pb, OptimizerSettings("lbfgs", iterations=12, step_max_fraction=fraction))
    a = np.array([float(d["a"][0]) for d in hist.designs])
    steps = np.abs(np.diff(a))
    assert np.all(steps <= 2.0 * fraction * (1 + 1e-12))
    assert steps[0] == pytest.approx(2.0 * fraction, rel=1e-12)
    reached = int(np.argmax(np.abs(a - 0.3) < 1e-6))
    assert a[reached] == pytest.approx(0.3, abs=1e-6)
    assert reached == (7 if fraction == 0.05 else 2)
