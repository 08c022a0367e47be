"""Exact gradients through the load history (issue: gradients and design).

References: central finite differences of the same differentiable run (float64, step
1e-4 in the scaled design variables, where no contact node changes state within the
step), Taylor remainders (second-order convergence), and the derivative of the
material-point solution for homogeneous frictionless upsetting (errata item 6: exactly
homogeneous, so d(force)/d(s0) of the FE run equals that of one material point).

One small frictional scene (3 x 3 q1p0 billet, Coulomb 0.3, 30 % upset in 10 steps) is compiled once
and shared by the FD check, the Taylor test and the design loop.  It runs on the sparse
backend (klujax), so its reverse pass refines each adjoint solve with the factorization the
forward pass kept (jaxform.solver.adjoint_solve), which the FD check then covers.
"""

from contextlib import contextmanager
from dataclasses import replace
from functools import cache

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from fd_check import directional_derivatives

from jaxform import solver
from jaxform.cli import main
from jaxform.config import ConfigError, load_config
from jaxform.design import OptimizerSettings, available_groups, build_problem, optimize, taylor_test
from jaxform.design.objectives import ForgingWork, SideStraightness
from jaxform.design.problem import side_nodes
from jaxform.design.taylor import Window
from jaxform.gradients import GradientRunError, check, kept_steps, trajectory
from jaxform.materialpoint import Ram, uniaxial_compression
from jaxform.scenes import build_scene

BASE = {
    "billet": {"diameter_mm": 5.0, "height_mm": 7.5},
    "mesh": {"nr": 3, "nz": 3, "element": "q1p0"},
    "die": {"speed_mm_s": 0.075, "reduction": 0.3},
    "friction": {"model": "coulomb", "mu": 0.3},
    "time": {"dt_s": 3.0},
    "output": {"fields": False, "plots": False},
}


class BulgeAndWork:
    """Side straightness (mm^2) plus a small multiple of the forging work: touches the
    final shape, the force history (contact multipliers) and, through them, everything."""

    def __init__(self, scene):
        self.side = SideStraightness(side_nodes(scene))
        self.work = ForgingWork()
        self.unit = "mm^2"

    def __call__(self, traj, inputs):
        return self.side(traj, inputs) + 1e-4 * self.work(traj, inputs)


REFINEMENTS = []  # (steps, converged) of each refined adjoint solve, as the program runs


@contextmanager
def recording_refinements():
    """Programs traced inside record each refined adjoint solve in REFINEMENTS."""
    original = solver.refined_solve

    def spy(*args, **kwargs):
        y, steps, ok = original(*args, **kwargs)
        jax.debug.callback(lambda s, o: REFINEMENTS.append((int(s), bool(o))), steps, ok)
        return y, steps, ok

    solver.refined_solve = spy
    try:
        yield
    finally:
        solver.refined_solve = original


@cache
def friction_problem():
    sc = build_scene(load_config(dict(BASE, solver={"linear": "sparse"})))
    pb = build_problem(
        sc, groups=available_groups(sc), objective=BulgeAndWork(sc), single_program=True
    )
    with recording_refinements():  # the one program every test here runs is compiled now
        pb.value_and_grad(pb.start)
    return pb


@cache
def start_gradient():
    pb = friction_problem()
    val, grad, _ = pb.value_and_grad(pb.start)
    return float(val), grad


def test_reverse_pass_refines_with_the_forward_factorizations():
    """All 10 steps fit the default memory budget; each reverse step solves J^T y = b by
    refinement with the klujax factorization its forward step kept (of the Newton
    iterate before the root), to a componentwise backward error of 4 ulps in at most 4
    refinement steps, never falling back to a new factorization."""
    pb = friction_problem()
    n = len(pb.times)
    assert pb.scene.linear.backend == "sparse" and kept_steps(pb.scene, n) == n
    REFINEMENTS.clear()
    pb.value_and_grad(pb.start)
    assert len(REFINEMENTS) == n, REFINEMENTS
    assert all(ok and 1 <= steps <= 4 for steps, ok in REFINEMENTS), REFINEMENTS


def test_every_group_is_available_on_the_friction_scene():
    pb = friction_problem()
    assert [g.name for g in pb.groups] == [
        "material",
        "friction",
        "speed",
        "preform",
        "nodes",
        "die",
    ]
    assert np.all(np.diff(pb.times) > 0)


@pytest.mark.parametrize("group", ["material", "friction", "speed", "preform", "nodes", "die"])
def test_gradient_against_central_differences(group):
    """dJ/du . du against (J(u + h du) - J(u - h du)) / 2h, h = 1e-4 (truncation error
    O(h^2) ~ 1e-8): relative error <= 1e-5."""
    pb = friction_problem()
    _, grad = start_gradient()
    exact, fd = directional_derivatives(pb, grad, group)
    assert exact != 0.0
    assert abs(fd - exact) <= 1e-5 * abs(exact), (group, fd, exact)


def test_taylor_remainders_converge_at_second_order():
    """Every group: |J(u + h du) - J(u) - h dJ.du| shrinks like h^2 (rates >= 1.9) while
    the first-order remainder shrinks like h (rates about 1)."""
    rows = taylor_test(friction_problem())
    for row in rows:
        assert row.min_rate >= 1.9, (row.group, row.rate1)
        assert np.all(row.rate0 < 1.5), (row.group, row.rate0)


def test_design_loop_lowers_the_objective():
    """L-BFGS over every group (bounded): the objective falls monotonically, by at least
    30 % in 3 iterations (measured 0.131 -> 0.074, -44 %), and every design stays inside
    its bounds."""
    pb = friction_problem()
    hist = optimize(pb, OptimizerSettings("lbfgs", iterations=3))
    assert len(hist.objective) >= 2
    assert hist.objective[-1] <= 0.7 * hist.objective[0], hist.objective
    assert np.all(np.diff(hist.objective) <= 0)
    lo, hi = pb.bounds()
    for d in hist.designs:
        for k in d:
            assert np.all(d[k] >= np.asarray(lo[k]) - 1e-12)
            assert np.all(d[k] <= np.asarray(hi[k]) + 1e-12)


@pytest.mark.slow  # compiles a second gradient program (~1.5 min on 2 cores)
def test_homogeneous_force_gradient_is_the_material_point_derivative():
    """Frictionless upsetting is homogeneous, so F(t) = sigma(t) pi (R0 lambda_r(t))^2 of
    one material point driven with the same steps; d F_end / d s0 of the FE run (implicit
    adjoint through the steps) equals the derivative of the material-point solution
    (central differences) to 1e-6 relative (measured 3e-7)."""
    cfg = dict(
        BASE,
        friction={"model": "none"},
        time={"dt_s": 1.0},
        die={"speed_mm_s": 0.075, "reduction": 0.2},
        mesh={"nr": 2, "nz": 2, "element": "q1p0"},
    )
    sc = build_scene(load_config(cfg))
    times = jnp.asarray(sc.step_targets())
    law = sc.model.law

    def fe(s0):
        inp = replace(sc.inputs, params=replace(sc.inputs.params, s0_MPa=s0))
        traj = trajectory(sc, inp, times)
        return traj.force_N[-1], traj

    def mp(s0):
        params = replace(sc.inputs.params, s0_MPa=s0)
        r = uniaxial_compression(
            law,
            params,
            final_strain=1.0,
            n_steps=1,
            ram=Ram(0.075, 7.5),
            times_s=times,
        )
        return r["stress_MPa"][-1] * jnp.pi * (2.5 * r["lateral_stretch"][-1]) ** 2

    s0 = sc.inputs.params.s0_MPa
    (f_fe, traj), g_fe = jax.value_and_grad(fe, has_aux=True)(s0)
    check(traj)
    # reference: central differences of the material-point solution (h = 1e-3 MPa;
    # truncation ~1e-9 relative).  Not AD: the driver's lateral solve is a plain Newton
    # while loop, and differentiating its iterations is off by 5 % here.
    mp_jit = jax.jit(mp)
    f_mp = mp_jit(s0)
    g_mp = (mp_jit(s0 + 1e-3) - mp_jit(s0 - 1e-3)) / 2e-3
    assert abs(f_fe - f_mp) <= 1e-6 * abs(f_mp)
    assert abs(g_fe - g_mp) <= 1e-6 * abs(g_mp), (float(g_fe), float(g_mp))
    assert g_mp > 0  # a harder material needs more force


@pytest.mark.slow  # compiles the forward-only program
def test_failed_step_raises_at_the_boundary():
    """A schedule of one step to 30 % upset (the forward run needs cutbacks there): the
    differentiable run has none, carries the failure code out of jit, and check() names
    the step instead of returning garbage."""
    sc = friction_problem().scene
    traj = trajectory(sc, sc.inputs, jnp.asarray([sc.t_end]))
    with pytest.raises(GradientRunError, match="step 1"):
        check(traj)


def test_design_config_errors_name_the_key():
    with pytest.raises(ConfigError, match="design.variables"):
        load_config(dict(BASE, design={"variables": ["shape"]}))
    sc = build_scene(load_config(dict(BASE, design={"material_params": ["nope_MPa"]})))
    with pytest.raises(ConfigError, match="design.material_params"):
        build_problem(sc, times=sc.step_targets())
    sc = build_scene(load_config(dict(BASE, design={"objective": "force_misfit"})))
    with pytest.raises(ConfigError, match="design.target_csv"):
        build_problem(sc, times=sc.step_targets())


@pytest.mark.slow
def test_taylor_test_cli_on_the_friction_scene(capsys):
    """`jaxform taylor-test configs/upsetting_friction.toml` with its defaults (h = 1 .. 1/8,
    every design group; 10 x 10, 57 steps, Coulomb 0.3, forging work) passes: with the
    fixed steps ~40 contact nodes over 57 steps put contact onsets and stick/slip switches
    inside h = 1 .. 1/8 (min rate 0.52 before the window search); now the steps whose runs
    change the active set are skipped and the window moves down until it stays on one, or
    ends at the noise floor.  Reference: rate 2 of the second-order remainder, >= 1.9."""
    code = main(["taylor-test", "configs/upsetting_friction.toml"])
    out = capsys.readouterr().out
    assert code == 0, out
    assert float(out.strip().splitlines()[-1].split("=")[1]) >= 1.9, out
    assert "window h =" in out and "skipped" in out, out


@pytest.mark.slow
def test_design_cli_writes_history_and_plots(tmp_path):
    code = main(
        [
            "design",
            "configs/preform_design.toml",
            "--out",
            str(tmp_path),
            "--set",
            "design.iterations=3",
        ]
    )
    assert code == 0
    for name in ("design_history.csv", "objective.png", "shapes.png", "config.toml"):
        assert (tmp_path / name).exists()
    from jaxform.io import read_csv

    h = read_csv(tmp_path / "design_history.csv")
    assert h["objective"][-1] < 0.5 * h["objective"][0]


class _KinkedProblem:
    """A design problem stand-in: J(u) = sum(u^2) + 3 sum(u) on one active set, and a
    different active set (and a kink: J gains |u - u0| terms) for perturbations larger
    than ``kink`` in size; ``wrong`` scales the gradient it reports."""

    def __init__(self, kink=0.002, wrong=1.0):
        from types import SimpleNamespace

        self.groups = (SimpleNamespace(name="a"),)
        self.start = {"a": np.array([0.3, -0.2, 0.1])}
        self.kink, self.wrong = kink, wrong

    def _run(self, design):
        u = design["a"]
        off = float(np.max(np.abs(u - self.start["a"])))
        status = np.array([[1, 2 if off > self.kink else 1]])
        j = float(np.sum(u**2) + 3.0 * np.sum(u) + (5.0 * off if off > self.kink else 0.0))
        return j, SimpleTraj(status)

    def value(self, design):
        return self._run(design)

    def value_and_grad(self, design):
        j, traj = self._run(design)
        return j, {"a": self.wrong * (2.0 * design["a"] + 3.0)}, traj


class SimpleTraj:
    def __init__(self, status):
        self.contact_status = status


def test_taylor_window_skips_steps_that_cross_an_active_set_change():
    """Reference: the stand-in's J is a quadratic on the base active set (R1 = |du|^2 h^2
    exactly) and has a kink beyond |h du| > 0.002: the default steps h = 1 .. 1/8 (|du| ~
    0.01 per entry) cross it, so the window moves down to the steps that stay on the
    active set, where the rate is 2 to 1e-6; a wrong gradient (x 1.01) is still caught
    (rate ~1), and a remainder below the noise floor passes as exact to the noise."""
    rows = taylor_test(_KinkedProblem())
    row = rows[0]
    assert len(row.skipped) >= 1 and row.skipped[0] == 1.0
    assert len(row.h) == 4 and row.h[0] < 1.0
    np.testing.assert_allclose(row.rate1, 2.0, atol=1e-6)
    assert row.min_rate == pytest.approx(2.0, abs=1e-6)
    bad = taylor_test(_KinkedProblem(wrong=1.01))[0]
    assert bad.min_rate < 1.2
    # a J exactly linear in the direction: every remainder is at the noise floor
    lin = _KinkedProblem()
    lin._run = lambda d: (float(3.0 * np.sum(d["a"])), SimpleTraj(np.array([[1, 1]])))
    lin.value_and_grad = lambda d: (*lin._run(d)[:1], {"a": np.full(3, 3.0)}, lin._run(d)[1])
    flat = taylor_test(lin)[0]
    assert flat.min_rate == float("inf") and not flat.measured.any()
    # every step crosses the kink (kink at 0): no window, nothing checked, so it fails
    never = taylor_test(_KinkedProblem(kink=0.0), window=Window(max_halvings=2))[0]
    assert len(never.h) == 0 and never.min_rate == 0.0


def test_taylor_window_moves_down_while_the_cubic_term_rivals_the_quadratic():
    """Reference: J = 3 s - 0.01 s^2 + c s^3 with s = sum(u - u0) (exact gradient 3 per
    entry), c chosen so that the h^2 and h^3 terms of R1 cancel at h = 0.35 (as on the
    seed scene's die group): the rates over h = 1 .. 1/8 swing far from 2, so the window
    moves down until they reach 1.9; with a gradient 0.1 % off the rates fall to ~1 on
    the way down and the test fails."""
    from jaxform.design.taylor import SCALE

    du = SCALE.get("a", 0.01) * np.random.default_rng([3, *b"a"]).standard_normal(3)
    c = 0.01 / (0.35 * float(np.sum(du)))
    for wrong, passes in ((1.0, True), (1.001, False)):
        p = _KinkedProblem(kink=1e9, wrong=wrong)
        u0 = p.start["a"].copy()

        def run(d, u0=u0):
            s = float(np.sum(d["a"] - u0))
            return 3.0 * s - 0.01 * s**2 + c * s**3, SimpleTraj(np.array([[1, 1]]))

        p._run = run
        p.value_and_grad = lambda d, p=p, w=wrong: (*p._run(d)[:1], {"a": np.full(3, 3.0 * w)},
                                                     p._run(d)[1])  # fmt: skip
        row = taylor_test(p, h=(1.0, 0.5, 0.25, 0.125), seed=3)[0]
        assert (row.min_rate >= 1.9) == passes, (row.h, row.rate1)
        if passes:
            assert row.h[0] < 0.125 and len(row.h) == 4, row.h  # it moved past the crossing


def test_taylor_window_takes_the_smooth_side_of_a_base_run_on_a_kink():
    """Reference: J = sum(u^2) + 3 sum(u) whose active set changes for any step with
    sum(u - u0) > 0 (the base run at a threshold, as a node exactly at its stick/slip
    limit): along that side no step stays on the active set; along the other the
    remainder is exactly quadratic (rate 2 to 1e-6), so the test passes along -du."""
    p = _KinkedProblem(kink=1e9)
    u0 = p.start["a"].copy()

    def run(d):
        s = float(np.sum(d["a"] - u0))
        status = np.array([[1, 2 if s > 0 else 1]])
        return float(np.sum(d["a"] ** 2) + 3.0 * np.sum(d["a"])), SimpleTraj(status)

    p._run = run
    rows = [taylor_test(p, seed=k, window=Window(max_halvings=2))[0] for k in range(4)]
    for row in rows:
        assert row.min_rate == pytest.approx(2.0, abs=1e-6), (row.sign, row.rate1)
    assert {row.sign for row in rows} == {1.0, -1.0}  # random directions on either side


def test_taylor_direction_of_a_geometric_group_is_capped_by_the_stroke():
    """Prandtl's punch presses 1.8 um: the die group's default direction (0.01 mm per
    point) lifted the punch off the material (J 0.505 -> 0.127 at h = 1) and the nodes
    group's distorted elements by more than the whole motion, and the default Taylor
    test failed (min rate 1.61).  A geometric group's direction is capped at 5 % of the
    run's stroke (here 2e-3 mm -> 1e-4 mm scale); a group that is not geometric keeps its
    scale."""
    from jaxform.design.taylor import SCALE, STROKE_FRACTION

    seen = []

    class Problem(_KinkedProblem):
        def __init__(self, name):
            super().__init__(kink=1e9)
            from types import SimpleNamespace

            self.groups = (SimpleNamespace(name=name),)
            self.start = {name: np.zeros(50)}

        def _run(self, design):
            u = next(iter(design.values()))
            seen.append(np.abs(u).max())
            traj = SimpleTraj(np.array([[1, 1]]))
            traj.stroke_mm = np.array([0.0, 1e-3, 2e-3])
            return float(np.sum(u**2) + 3.0 * np.sum(u)), traj

        def value_and_grad(self, design):
            j, traj = self._run(design)
            u = next(iter(design.values()))
            return j, {self.groups[0].name: 2.0 * u + 3.0}, traj

    for name, scale in (("die", STROKE_FRACTION * 2e-3), ("material", SCALE["material"])):
        seen.clear()
        taylor_test(Problem(name), h=(1.0, 0.5))
        first = seen[1]  # the base run, then h = 1
        assert 1.0 * scale < first < 4.0 * scale, (name, first, scale)  # max of 50 normals


@pytest.mark.slow
def test_taylor_test_cli_passes_on_prandtls_punch(capsys):
    """`jaxform taylor-test configs/prandtl_punch.toml` with its defaults exits 0 (every
    group's rate >= 1.9; measured min rate 1.954, 880 s on a loaded 2-core machine)."""
    code = main(["taylor-test", "configs/prandtl_punch.toml"])
    assert code == 0, capsys.readouterr().out[-2000:]
