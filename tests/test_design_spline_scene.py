"""The die spline group, the two-stage design objectives and the sampling optimizers on a
tiny real scene: experiments/spline_die_design.toml on a 3 x 3 mesh (a closed die whose
roof is a spline of 2 free control heights, fillet radius >= 5 mm), 15 steps.  One
compiled value-and-gradient program (module fixture; ~4 min cold on 2 busy cores, hence
slow)."""

import csv
from dataclasses import replace
from functools import cache

import numpy as np
import pytest

from jaxform.cli import main
from jaxform.config import load_config
from jaxform.design import CmaEs, LhsRsm, OptimizerSettings, build_problem, optimize
from jaxform.design.problem import build_objective, lap_penalty
from jaxform.io import read_csv
from jaxform.scenes import build_scene

pytestmark = pytest.mark.slow

SCENE = "experiments/spline_die_design.toml"
TINY = [
    "mesh.nr=3",
    "mesh.nz=3",
    "design.die_spline_controls=2",
    "design.die_fillet_radius_min_mm=5",
]
# every new term, weighted to contribute alike
TERMS = [
    "design.terms=['die_fill', 'flash_volume', 'lap', 'press_capacity']",
    "design.term_weights=[1.0, 0.001, 1.0, 20.0]",
    "design.press_capacity_N=2000",
]


@cache
def problem():
    """The tiny scene with every term; the lap term's limit at 200 deg (above the config's
    range: the billet's sides are straight or bulged, every free-surface wedge is >= 180
    deg, so 200 makes the term and its gradient nonzero)."""
    sc = build_scene(load_config(SCENE, TINY + TERMS))
    ws = build_objective(sc)
    lap = lap_penalty(sc, 200.0)
    terms = tuple(lap if n == "lap" else t for n, t in zip(ws.names, ws.terms))
    return build_problem(sc, objective=replace(ws, terms=terms), single_program=True)


def _at(design, u):
    return {"die_spline": np.asarray(u, dtype=float)} | {
        k: v for k, v in design.items() if k != "die_spline"
    }


def test_spline_design_gradient_matches_central_differences():
    """Reference: central differences (h = 1e-4 mm along a unit direction; truncation
    ~1e-8 relative) of the weighted sum of die_fill, flash_volume, lap and press_capacity
    plus the spline's constraint penalty, at the start (every term nonzero, no penalty)
    and at u = (0.4, -0.4) mm where the fillet-radius rows are violated (penalty > 0):
    the adjoint gradient agrees to 1e-5 relative."""
    pb = problem()
    rep = pb.report(pb.start)
    for term in ("die_fill", "flash_volume", "lap", "press_capacity"):
        assert rep[term] > 0.0, rep
    assert rep["constraint_penalty"] == 0.0
    bent = _at(pb.start, [0.4, -0.4])
    assert pb.report(bent)["constraint_penalty"] > 0.0
    du = np.array([0.6, -0.8])
    h = 1e-4
    for design in (pb.start, bent):
        _, grad, _ = pb.value_and_grad(design)
        exact = float(np.dot(np.asarray(grad["die_spline"]), du))
        u = np.asarray(design["die_spline"])
        plus, minus = (float(pb.value(_at(design, u + s * h * du))[0]) for s in (1, -1))
        fd = (plus - minus) / (2 * h)
        assert exact != 0.0 and abs(fd - exact) <= 1e-5 * abs(exact), (exact, fd)


def test_sampling_optimizers_run_the_scene_within_its_bounds():
    """LHS-RSM (3 runs per variable: 6 runs fit the full quadratic in 2 variables, one
    verifies its minimum) and CMA-ES (4 per generation, 8 runs): one row per run with the
    runs used so far, every design inside the box, a run that failed (a die lowered into
    an overfilled cavity) a NaN counted as rejected, most runs finite."""
    pb = problem()
    lo, hi = (np.asarray(b["die_spline"]) for b in pb.bounds())
    lhs = optimize(pb, LhsRsm(samples_per_variable=3, seed=0))
    cma = optimize(pb, CmaEs(population=4, max_simulations=8, seed=0))
    assert lhs.simulations == list(range(1, 8)) and "full quadratic" in lhs.stop_reason
    assert cma.simulations == list(range(1, 9))
    for hist in (lhs, cma):
        for d in hist.designs:
            assert np.all(d["die_spline"] >= lo) and np.all(d["die_spline"] <= hi)
        cols = hist.columns(pb)
        assert {"simulations", "best_objective", "spline_z1_mm"} <= set(cols)
        failed = int(np.isnan(hist.objective).sum())  # a die that overfills the cavity
        assert failed == hist.rejected and failed < len(hist.objective) / 2, hist.objective


def test_gradient_design_counts_one_simulation_per_gradient():
    """L-BFGS, 2 iterations: each row's simulations is the value-and-gradient runs so far
    (1 at the start, then one more per trial the line search made); the objective never
    rises."""
    pb = problem()
    hist = optimize(pb, OptimizerSettings("lbfgs", iterations=2))
    assert hist.simulations[0] == 1 and hist.simulations[-1] == hist.evaluations
    assert np.all(np.diff(hist.simulations) >= 1)
    assert np.all(np.diff(hist.objective) <= 0.0)


def test_design_cli_runs_cmaes_with_a_report(tmp_path, capsys):
    """`jaxform design` with design.optimizer = cmaes (8 runs): progress per run, the
    history with its simulations column, and design_report.csv with each term of the
    weighted sum and each spline constraint's value, limit and margin at the start and
    the best design."""
    args = ["design", SCENE, "--out", str(tmp_path), "--set", "design.optimizer=cmaes",
            "--set", "design.max_simulations=8", "--set", "design.population=4"]  # fmt: skip
    for s in TINY + TERMS:
        args += ["--set", s]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "simulation    8:" in out and "8 simulations" in out, out
    h = read_csv(tmp_path / "design_history.csv")
    assert list(h["simulations"]) == list(range(1, 9))
    with open(tmp_path / "design_report.csv", newline="") as fh:
        names = [row["quantity"] for row in csv.DictReader(fh)]
    for q in ("objective", "die_fill", "flash_volume", "lap", "press_capacity",
              "die_spline.draft_deg.margin", "die_spline.fillet_radius_mm.limit"):  # fmt: skip
        assert q in names, names
