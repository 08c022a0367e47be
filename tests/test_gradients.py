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

from jaxform import solver
from jaxform.cli import main
from jaxform.config import ConfigError, load_config
from jaxform.design import OptimizerSettings, available_groups, build_problem, optimize, taylor_test
from jaxform.design.objectives import ForgingWork, SideStraightness
from jaxform.design.problem import side_nodes
from jaxform.gradients import GradientRunError, check, kept_steps, trajectory
from jaxform.materialpoint import uniaxial_compression
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
    rng = np.random.default_rng(7)
    u = {k: np.asarray(v) for k, v in pb.start.items()}
    du = rng.standard_normal(u[group].shape)
    du /= np.linalg.norm(du)  # unit direction: no accidentally tiny derivative
    exact = float(np.dot(np.asarray(grad[group]), du))
    h = 1e-4
    vals = []
    for s in (1.0, -1.0):
        d = dict(u)
        d[group] = u[group] + s * h * du
        vals.append(float(pb.value(d)[0]))
    fd = (vals[0] - vals[1]) / (2 * h)
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
            ram_speed_mm_s=0.075,
            height_mm=7.5,
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
    """`jaxform taylor-test configs/upsetting_friction.toml --h 0.01 ...` (10 x 10, 57
    steps, Coulomb 0.3, forging work) passes for the material, speed, preform and nodes
    groups (measured rates 1.98-2.05), and from h = 0.005 for friction (at 0.01 its first
    rate is 1.67: a stick/slip switch between 0.01 and 0.005).  With the default
    h = 1 .. 1/8 the remainders of the groups that move contact onsets or stick/slip
    switches (friction, preform, nodes, die) do not converge: ~40 contact nodes over 57
    steps put kinks of the piecewise-smooth
    objective inside that range (min rate 0.52).  The die group has no clean window on this
    scene (at h = 0.01 its second-order remainder, 1.3e-6 against a first-order 0.10, is
    already at the Newton tolerance's noise floor); it passes on the 3 x 3 scene above."""
    for h0, groups in ((0.01, ["material", "speed", "preform", "nodes"]), (0.005, ["friction"])):
        code = main(
            [
                "taylor-test",
                "configs/upsetting_friction.toml",
                "--h",
                *(str(h0 / 2**k) for k in range(4)),
                "--groups",
                *groups,
            ]
        )
        out = capsys.readouterr().out
        assert code == 0, out
        assert float(out.strip().splitlines()[-1].split("=")[1]) >= 1.9, out


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
