"""A process design's objective read from its forward run (no replay): what a sampling
optimizer evaluates, one forward simulation a design as the commercial codes run.

The tiny process of tests/test_process_die_spline.py (the seed billet on 3 x 3, a flat blow,
then a closed cone die with a flash land, stopped 0.1 mm short so that its cavity is not
full).  References, each computed by other code than the
design's objectives: the history's peak force (the run's own rows), its die fill and flash
volume (:mod:`jaxform.postprocess`, the conformed polygon and the boundary integral, against
the design's traced terms, which agree to 1e-9 on the tutorial).  The value of a replay at
the run's own design is compared with this reading in the slow
tests/test_robust_design.py::test_a_design_far_from_its_plan_is_evaluated_on_a_new_plan
(relative 1e-9)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from jaxform.design.process_problem import build_process_problem, config_objective
from jaxform.process import prepare, run_process
from jaxform.process_config import load_typed
from jaxform.process_gradients import ProcessPlan, forward_trajectory

sys.path.insert(0, str(Path(__file__).parent))
from test_process_die_spline import GROUPS, document  # noqa: E402


@pytest.fixture(scope="module")
def run():
    doc = document()
    doc["process"]["operation"][1]["travel_mm"] = 0.2  # stopped short: the cavity not full
    process = load_typed(doc)
    result = run_process(process.operations, prepare(process.operations))
    plan = ProcessPlan.of(result)
    d = process.operations[0].config.design
    problem = build_process_problem(plan, GROUPS, config_objective(plan, d))
    return result, problem


def test_the_forward_reading_gives_the_history_outputs(run):
    result, problem = run
    ptraj = forward_trajectory(result)
    assert len(ptraj.operations) == len(result.runs)
    inputs, _ = problem._inputs(problem.start)
    terms = {k: float(v) for k, v in problem.objective.values(ptraj, inputs).items()}
    first, second = (r.result.history for r in result.runs)
    # the first blow's press-capacity penalty reads its peak force, the run's largest row
    np.testing.assert_allclose(np.asarray(ptraj.operations[0].force_N), first["force_N"])
    assert float(np.max(first["force_N"])) > 200.0  # above design.press_capacity_N: active
    assert terms["first.press_capacity"] > 0.0
    # the second blow's flash and underfill, as its history's last row reads them
    assert terms["flash_volume"] == pytest.approx(second["flash_volume_mm3"][-1], rel=1e-9)
    assert terms["die_fill"] == pytest.approx(1.0 - second["die_fill"][-1], abs=1e-9)
    assert 0.0 < terms["die_fill"] < 1.0 and terms["flash_volume"] > 0.0
    # the value: the configured weights (all 1) and the splines' penalty (0 at the start)
    want = sum(terms.values())
    assert problem.value_of(problem.start, ptraj) == pytest.approx(want, rel=1e-12)


def test_each_operation_ends_on_the_mesh_and_clock_it_left(run):
    result, _ = run
    ptraj = forward_trajectory(result)
    for r, traj in zip(result.runs, ptraj.operations):
        h = r.result.history
        assert traj.time_s.shape == (len(h["time_s"]),) and float(traj.time_s[0]) == 0.0
        assert traj.codes.shape == (len(h["time_s"]) - 1,) and not np.any(traj.codes)
        n = r.result.final_scene.mesh.coords.shape[0]
        assert traj.positions.shape == (n, 2)
