"""Gradients through remeshing (issue: automatic remeshing, item 6).

A gradient run of a scene with ``[remesh]`` takes the meshes of its forward run
(:class:`jaxform.gradients.RemeshPlan`): each remesh is the forward run's fixed map
(:class:`jaxform.remesh.StateMap`), differentiated like the steps.  References: central
finite differences of the same differentiable run (step 1e-4 in the scaled design
variables, relative error <= 1e-5), Taylor remainders (rates >= 1.9), and the forward
run itself (the gradient run's force history equals it to the Newton tolerance).

One small frictional scene (3 x 3 q1p0 billet, Coulomb 0.3, 30 % upset in 20 steps, a new
mesh every 5 steps: 3 remeshes, every mesh in one capacity bucket, so one compiled
program) is shared by every test here.
"""

from dataclasses import replace
from functools import cache

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from fd_check import directional_derivatives

from jaxform.config import ConfigError, check_gradient_run, load_config
from jaxform.design import OptimizerSettings, build_problem, optimize, taylor_test
from jaxform.design.objectives import ForceMisfit, ForgingWork
from jaxform.gradients import _remeshed_trajectory, step_chunks, trajectory
from jaxform.scenes import build_scene
from jaxform.simulation import simulate

GROUPS = ("material", "friction", "preform")
BASE = {
    "billet": {"diameter_mm": 5.0, "height_mm": 7.5},
    "mesh": {"nr": 3, "nz": 3, "element": "q1p0"},
    "die": {"speed_mm_s": 0.075, "reduction": 0.3},
    "friction": {"model": "coulomb", "mu": 0.3},
    "time": {"dt_s": 1.5},
    "output": {"fields": False, "plots": False},
    "remesh": {"every_steps": 5, "element_size_mm": 1.5},
}


@cache
def problem():
    sc = build_scene(load_config(BASE))
    return build_problem(sc, groups=GROUPS, objective=ForgingWork(), single_program=True)


@cache
def start_gradient():
    pb = problem()
    val, grad, traj = pb.value_and_grad(pb.start)
    return float(val), grad, traj


def test_the_gradient_run_takes_the_forward_runs_meshes():
    """3 remeshes, all four meshes in one capacity bucket; every step converges and the
    force history equals the forward run's (same steps, same meshes) to 1e-7 relative
    (both solve each step to the Newton tolerance).  Each replayed step starts from the
    forward run's converged unknowns (MeshSegment.converged) and so converges at once:
    0 Newton iterations, where the forward run took 3-13 a step."""
    pb = problem()
    segs = pb.plan.segments
    assert len(segs) == 4 and [s.n_steps for s in segs] == [5, 5, 5, 5]
    assert len({s.padded.bucket for s in segs}) == 1
    assert all(s.transfer is not None for s in segs[1:]) and segs[0].transfer is None
    _, _, traj = start_gradient()
    assert np.all(np.asarray(traj.codes) == 0)
    assert all(s.converged.shape == (s.n_steps, s.scene.model.layout.n_dofs) for s in segs)
    assert np.all(np.asarray(traj.iterations) == 0), np.asarray(traj.iterations)
    inputs, _ = pb.run_inputs(pb.start)
    res = simulate(replace(pb.scene, inputs=inputs))
    assert len(res.remeshes) == 3
    np.testing.assert_allclose(np.asarray(traj.time_s), res.history["time_s"], rtol=1e-12)
    assert np.all(res.history["newton_iterations"][1:] >= 3)
    f = res.history["force_N"]
    assert np.max(np.abs(np.asarray(traj.force_N) - f)) <= 1e-7 * np.max(f)
    # the final fields live on the last mesh
    assert traj.positions.shape == (segs[-1].scene.model.layout.n_nodes, 2)


def test_a_meshs_steps_run_in_runs_of_8_4_2_1():
    """A mesh's steps replay in runs of 8 and then the binary digits of the rest, largest
    first (reference: the binary expansion): chunked, the meshes of one bucket, whatever
    their step counts (here 1 to 99), run four step programs at most."""
    assert step_chunks(5) == (4, 1) and step_chunks(21) == (8, 8, 4, 1)
    assert step_chunks(8) == (8,) and step_chunks(0) == ()
    lengths = set()
    for n in range(1, 100):
        chunks = step_chunks(n)
        assert sum(chunks) == n and list(chunks) == sorted(chunks, reverse=True)
        assert len([c for c in chunks if c < 8]) == bin(n % 8).count("1")
        lengths |= set(chunks)
    assert lengths == {8, 4, 2, 1}


@pytest.mark.slow  # compiles the bucket's programs of 4 and 1 steps (~3 min on 2 cores)
def test_a_mesh_replayed_in_runs_of_steps_is_the_mesh_replayed_at_once():
    """Each mesh's 5 steps as runs of 4 and 1 (chunked, what a process replay does where
    that compiles fewer programs) against one run of 5: the same forces and final state
    (1e-9 relative: the same steps, other programs) and the same gradient of the forging
    work with respect to the step times (1e-8 relative)."""
    pb = problem()
    inputs, times = pb.run_inputs(pb.start)

    def work(t, chunked):
        traj = _remeshed_trajectory(pb.scene, inputs, t, pb.plan, chunked)
        return jnp.sum(traj.force_N), traj

    (w0, t0), g0 = jax.value_and_grad(work, has_aux=True)(times, False)
    (w1, t1), g1 = jax.value_and_grad(work, has_aux=True)(times, True)
    f0, f1 = np.asarray(t0.force_N), np.asarray(t1.force_N)
    assert f0.shape == f1.shape and np.max(np.abs(f1 - f0)) <= 1e-9 * np.max(np.abs(f0))
    assert np.allclose(np.asarray(t1.x), np.asarray(t0.x), rtol=1e-9, atol=1e-12)
    assert np.array_equal(np.asarray(t1.contact_status), np.asarray(t0.contact_status))
    g0, g1 = np.asarray(g0), np.asarray(g1)
    assert np.max(np.abs(g1 - g0)) <= 1e-8 * np.max(np.abs(g0)) and np.max(np.abs(g0)) > 0


@pytest.mark.parametrize("group", GROUPS)
def test_gradient_through_remeshes_against_central_differences(group):
    """dJ/du . du against (J(u + h du) - J(u - h du)) / 2h, h = 1e-4 (truncation O(h^2)):
    relative error <= 1e-5."""
    pb = problem()
    _, grad, _ = start_gradient()
    exact, fd = directional_derivatives(pb, grad, group)
    assert exact != 0.0
    assert abs(fd - exact) <= 1e-5 * abs(exact), (group, fd, exact)


def test_taylor_remainders_through_remeshes_converge_at_second_order():
    """Every group: second-order remainders shrink like h^2 (rates >= 1.9) while
    first-order ones shrink like h (rates < 1.5)."""
    for row in taylor_test(problem()):
        assert row.min_rate >= 1.9, (row.group, row.rate1)
        assert np.all(row.rate0 < 1.5), (row.group, row.rate0)


def test_design_through_remeshes_lowers_the_objective():
    """L-BFGS over material, friction and preform, each evaluation through 3 remeshes: the
    forging work falls monotonically and every design stays inside its bounds."""
    pb = problem()
    hist = optimize(pb, OptimizerSettings("lbfgs", iterations=2))
    assert len(hist.objective) >= 2
    assert hist.objective[-1] < hist.objective[0], hist.objective
    assert np.all(np.diff(hist.objective) <= 0)
    lo, hi = pb.bounds()
    for d in hist.designs:
        for k in d:
            assert np.all(d[k] >= np.asarray(lo[k]) - 1e-12)
            assert np.all(d[k] <= np.asarray(hi[k]) + 1e-12)


def test_a_remesh_map_is_the_same_in_numpy_and_traced_jax():
    """The forward run applies each StateMap with NumPy, the gradient run with JAX: the two
    agree to 1e-12 on the gradient run's state at the first remesh (step 5)."""
    pb = problem()
    seg0, seg1 = pb.plan.segments[:2]
    inputs, times = pb.run_inputs(pb.start)
    one = replace(pb.plan, segments=(seg0,))  # the run up to the first remesh, padded
    traj = _remeshed_trajectory(seg0.scene, inputs, times[: seg0.n_steps], one)
    state, coords = traj.final_state, inputs.coords
    host, c_np = seg1.transfer.apply(jax.tree_util.tree_map(np.asarray, state), np.asarray(coords))
    traced, c_jx = seg1.transfer.apply(state, coords, jnp)
    np.testing.assert_allclose(np.asarray(c_jx), c_np, rtol=0, atol=1e-12)
    for a, b in zip(jax.tree_util.tree_leaves(traced), jax.tree_util.tree_leaves(host)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-12, atol=1e-12)
    # the new state lives on the new mesh
    assert traced.x.shape == (seg1.scene.model.layout.n_dofs,)


def test_remeshing_gradient_runs_need_the_plan_and_a_force_objective():
    """A trajectory of a remeshing scene without the forward run's plan, and a design
    objective that reads the initial mesh, are refused with one line."""
    with pytest.raises(ValueError, match="remeshed_schedule"):
        trajectory(problem().scene)
    over = ["remesh.every_steps=3"]
    cfg = load_config("configs/upsetting_friction.toml", over)
    check_gradient_run(cfg)  # forging_work: fine
    bad = load_config("configs/preform_design.toml", over)
    with pytest.raises(ConfigError, match="reads the initial mesh"):
        check_gradient_run(bad)


@pytest.mark.slow  # compiles the preform-only gradient program (31 s on 2 cores, 2026-11-25)
def test_preform_design_through_remeshes_recovers_a_force_curve():
    """Preform design alone (3 cosine modes) through the 3 remeshes: the objective is the
    misfit to the force-stroke curve of a known preform (amplitudes 0.1, -0.05, 0.05 of
    the radius); L-BFGS from the cylinder lowers it monotonically, by at least 90 % in 4
    iterations."""
    sc = problem().scene
    pb = build_problem(sc, groups=("preform",), objective=ForgingWork(), single_program=True)
    _, target = pb.value({"preform": np.array([0.1, -0.05, 0.05])})
    stroke, force = np.asarray(target.stroke_mm)[1:], np.asarray(target.force_N)[1:]
    fit = replace(pb, objective=ForceMisfit(stroke, force))
    hist = optimize(fit, OptimizerSettings("lbfgs", iterations=4))
    assert np.all(np.diff(hist.objective) <= 0), hist.objective
    assert hist.objective[-1] <= 0.1 * hist.objective[0], hist.objective
