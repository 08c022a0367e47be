"""Forward upsetting (issue: the seed's open-die upsetting end to end).

References: the material-point update driven with the same time steps (frictionless
upsetting is exactly homogeneous, errata item 6), SciPy Radau on the uniaxial ODEs,
central finite differences of the global residual, and the patch test (a distorted mesh
must reproduce a homogeneous deformation exactly).
"""

import re
from dataclasses import replace
from functools import cache

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from fd_check import jacobian_fd_error
from reference_ode import anand_uniaxial_reference

from jaxform.assembly import internal_forces
from jaxform.cli import main
from jaxform.config import load_config
from jaxform.io import read_csv
from jaxform.materialpoint import Ram, uniaxial_compression
from jaxform.postprocess import contact_profile, nodal_fields
from jaxform.rezone import gap_function
from jaxform.scenes import build_scene
from jaxform.simulation import SimulationError, simulate
from jaxform.status import OK
from jaxform.stepping import step_context

BASE = {
    "billet": {"diameter_mm": 5.0, "height_mm": 7.5},
    "die": {"speed_mm_s": 0.075, "reduction": 0.563},
    "time": {"dt_s": 1.0},
    "output": {"fields": False, "plots": False},
}


def scene(*overrides):
    return build_scene(load_config(BASE, list(overrides)))


@cache
def homogeneous_run(element, geometry="axisymmetric"):
    sc = scene(f"mesh.element={element}", "mesh.nr=3", "mesh.nz=3", f"mesh.geometry={geometry}")
    return sc, simulate(sc)


def positions(sc, res, k=-1):
    u, _, _ = nodal_fields(sc, res.fields["x"][k])
    return np.asarray(sc.inputs.coords) + u


# q4 slow: the same homogeneous path, and q4 runs in the patch and punch tests (CI time)
@pytest.mark.parametrize("element", ["q1q1", "q1p0", pytest.param("q4", marks=pytest.mark.slow)])
def test_frictionless_upsetting_is_the_material_point(element):
    """Force-stroke = material point with the same steps to 1e-6; side straight to 1e-8;
    within the time-discretization error (2 %, steps of ~1 % strain) of the Radau ODE."""
    sc, res = homogeneous_run(element)
    h = res.history
    law, params = sc.model.law, sc.inputs.params
    mp = jax.jit(
        lambda t: uniaxial_compression(
            law, params, final_strain=1.0, n_steps=1, ram=Ram(0.075, 7.5), times_s=t
        )
    )(jnp.asarray(h["time_s"][1:]))
    area = np.pi * (2.5 * np.asarray(mp["lateral_stretch"])) ** 2
    force_mp = np.asarray(mp["stress_MPa"]) * area
    rel = np.abs(h["force_N"][1:] - force_mp[1:]) / force_mp[1:]
    assert rel.max() <= 1e-6, rel.max()
    pos = positions(sc, res)
    side_r = pos[sc.mesh.node_sets["side"], 0]
    assert np.ptp(side_r) <= 1e-8 * side_r.mean()
    # against the exact ODE solution (constant ram speed)
    strain = np.asarray(mp["strain"])[1:]
    ref = anand_uniaxial_reference(None, strain, speed_over_height=0.01)[0]
    stress_fe = h["force_N"][1:] / area[1:]
    mask = strain > 0.05
    err = np.max(np.abs(stress_fe[mask] - ref[mask]) / ref[mask])
    assert err <= 0.02, err


def test_die_force_equals_reaction_and_no_penetration():
    """Sum of multipliers = reaction on the symmetry plane (1e-8 rel.); gaps >= -1e-8 mm."""
    sc, res = homogeneous_run("q1q1")
    st = res.final_state
    # reaction from the converged stresses (state at t_n = converged: dt = 0 step is identity)
    x = st.x
    f_int = internal_forces(
        sc.model, x, st.gauss, sc.inputs.coords, 1e-30, sc.inputs.params, sc.idx
    )
    reaction = float(jnp.sum(f_int[sc.idx.bottom_reaction_dofs]))  # symmetry plane pushes up
    force = res.history["force_N"][-1]
    assert abs(reaction - force) <= 1e-8 * force
    pos = positions(sc, res)
    gaps = gap_function(sc.inputs.die, st.t)(np.asarray(pos[np.asarray(sc.idx.contact_nodes)]))[0]
    assert gaps.min() >= -1e-8


@pytest.mark.parametrize("geometry", ["axisymmetric", "plane_strain"])
def test_contact_pressure_of_homogeneous_upsetting_is_the_uniform_stress(geometry):
    """Frictionless flat die, homogeneous deformation (3x3 q1p0): the contact pressure
    reported at every node in contact (multiplier / contact area) equals the uniform
    -sigma_zz to 1e-6 relative, at every fourth step and at the end; the edge node too
    (its area counts only the facets in contact, not the free side below it)."""
    sc, res = homogeneous_run("q1p0", geometry)
    rows = list(range(1, len(res.history["time_s"]), 4)) + [len(res.history["time_s"]) - 1]
    for k in rows:
        cp = contact_profile(
            sc, res.fields["x"][k], res.fields["slip_mm"][k], res.fields["contact_status"][k]
        )
        szz = res.fields["stress"][k][..., 1, 1]
        assert np.ptp(szz) <= 1e-9 * np.abs(szz).max()  # the field is uniform
        touching = cp["status"] > 0
        assert touching.sum() == 4  # the top row of nodes
        err = np.max(np.abs(cp["pressure_MPa"][touching] / -szz.mean() - 1.0))
        assert err <= 1e-6, (k, err, cp["pressure_MPa"][touching], -szz.mean())


@pytest.mark.parametrize("element", ["q1q1", "q1p0"])
def test_global_jacobian_against_finite_differences(element):
    """jacfwd-assembled Jacobian vs 4-point central differences (h = 1e-6 x scale of the
    unknown), contact active: relative error (Frobenius) <= 1e-6 (measured 3e-8 for q1p0)."""
    sc, res = homogeneous_run(element)  # 3x3 mesh at 56.3 % reduction, compiled once
    st = res.final_state
    rng = np.random.default_rng(1)
    x = st.x + 1e-4 * jnp.asarray(rng.standard_normal(st.x.shape)) * (st.x != 0)
    ctx = step_context(sc.model, st, sc.inputs, sc.idx, st.t + 0.5, 0.5)
    err = jacobian_fd_error(sc, x, ctx, h_rel=1e-6)
    assert err <= 1e-6, err
    assert np.any(np.asarray(x[sc.idx.mult_dofs[:, 0]]) > 0)  # contact active


def test_chunked_element_jacobians_equal_one_vmap():
    """Model.jacobian_chunk: the element Jacobians computed in padded chunks (9 elements in
    chunks of 4: 3 chunks, 3 padding copies) equal the single vmap (checked against finite
    differences above) to round-off, and so do R, the Gauss state and the status.  Round-off
    here: the two programs are fused differently, and the nested Anand root solves (stopped at
    rtol 1e-13) amplify last-bit differences; measured 3e-14 (Jacobian, R), 2.3e-13 (stress),
    tested at 1e-11.  And both equal jacfwd of Model.residual (the plain path) to 1e-11."""
    sc, res = homogeneous_run("q1q1")
    st = res.final_state
    ctx = step_context(sc.model, st, sc.inputs, sc.idx, st.t + 0.5, 0.5)
    outs = [
        jax.jit(replace(sc.model, jacobian_chunk=c).residual_and_jacobian)(st.x, ctx)
        for c in (0, 4)
    ]
    (r0, v0, g0, ok0, f0), (r1, v1, g1, ok1, f1) = outs
    assert int(ok0) == int(ok1) and abs(float(f1) / float(f0) - 1.0) <= 1e-11
    errs = [
        np.max(np.abs(r1 - r0)) / float(f0),  # R ~ 0 here: relative to the forces
        np.max(np.abs(v1 - v0)) / np.max(np.abs(v0)),
    ]
    errs += [
        np.max(np.abs(b - a)) / np.max(np.abs(a))
        for a, b in zip(jax.tree_util.tree_leaves(g0), jax.tree_util.tree_leaves(g1))
    ]
    print("relative differences (R, Jacobian, Gauss state):", errs)
    assert max(errs) <= 1e-11, errs
    # the two-pass assembly (residual pass solving every point, Jacobian pass at its
    # solution without solving) against forward-mode AD straight through the solving
    # residual: the same derivative (measured 1e-16 relative)
    dense = jax.jit(jax.jacfwd(lambda z: sc.model.residual(z, ctx)[0]))(st.x)
    direct = np.asarray(dense)[np.asarray(sc.idx.rows), np.asarray(sc.idx.cols)]
    err = np.max(np.abs(direct - np.asarray(v0))) / np.max(np.abs(direct))
    assert err <= 1e-11, err


@pytest.mark.parametrize("geometry", ["axisymmetric", "plane_strain"])
@pytest.mark.parametrize("element", ["q1q1", "q1p0", "q4"])
def test_patch_test_distorted_mesh(element, geometry):
    """A distorted 3x3 mesh under frictionless upsetting deforms homogeneously: every node at
    (lam_r R, lam_z Z) to 1e-9 mm and every Gauss point at the same stress (1e-8 rel.)."""
    sc = scene(
        f"mesh.element={element}",
        "mesh.nr=3",
        "mesh.nz=3",
        f"mesh.geometry={geometry}",
        "die.reduction=0.1",
        "time.dt_s=2.0",
    )
    coords = np.asarray(sc.inputs.coords).copy()
    interior = np.setdiff1d(
        np.arange(len(coords)),
        np.concatenate([sc.mesh.node_sets[k] for k in ("axis", "symmetry", "top", "side")]),
    )
    coords[interior] += np.array([[0.21, -0.17], [-0.13, 0.19], [0.16, 0.12], [-0.2, -0.1]])
    sc = replace(sc, inputs=replace(sc.inputs, coords=jnp.asarray(coords)))
    res = simulate(sc)
    pos = positions(sc, res)
    top = pos[sc.mesh.node_sets["top"], 1].mean() / 3.75
    side = pos[sc.mesh.node_sets["side"], 0].mean() / 2.5
    expected = coords * np.array([side, top])
    assert np.max(np.abs(pos - expected)) <= 1e-9
    stress = res.fields["stress"][-1].reshape(-1, 3, 3)
    assert np.max(np.abs(stress - stress[0])) <= 1e-8 * np.max(np.abs(stress[0]))


@cache
def seed_run():
    sc = scene()  # the seed scene: 10x10 q1q1, dt = 1 s (modified Newton: 'auto')
    return sc, simulate(sc)


@cache
def newton_seed_run():
    """The seed scene with full Newton (a new Jacobian every iteration): the reference of
    Newton's own convergence and of the backends that cannot keep a factorization."""
    sc = scene("solver.newton=newton")
    return sc, simulate(sc)


def test_a_chunk_takes_fewer_steps_where_their_fields_would_take_more():
    """``solver.chunk_output_mb`` bounds a chunk's per-step output fields (the 10 x 10 seed
    mesh: 405 unknowns, 100 elements x 4 Gauss points x (9 stress components, s, eqps, 3
    damage integrals), 21 contact candidates' slip and status: 48 292 bytes a step), so
    0.1 MB gives chunks of 2 steps (the progress callback's chunk ends), and
    the run is the 8-step chunks' run: the same steps and force history (1e-12
    relative) and iterations."""
    from jaxform.chunks import chunk_steps
    from jaxform.stepping import initial_state

    sc, ref = seed_run()
    small = replace(sc, chunk_output_mb=0.1)
    state = initial_state(sc.model, sc.inputs)
    n_cand = len(sc.idx.contact_nodes)
    per_step = 8 * (405 + 100 * 4 * 14) + n_cand * (8 + 4)
    assert per_step == 48_292 and state.x.shape == (405,) and n_cand == 21
    assert chunk_steps(small, state) == int(0.1e6 // per_step) == 2
    assert chunk_steps(sc, state) == sc.chunk == 8
    ends = []
    res = simulate(small, lambda p: ends.append(p["chunk_end"]))
    steps = len(ref.history["time_s"]) - 1
    assert sum(ends) == -(-steps // 2) and len(ends) == steps
    np.testing.assert_array_equal(res.history["time_s"], ref.history["time_s"])
    its = "newton_iterations"
    np.testing.assert_array_equal(res.history[its], ref.history[its])
    f, f_ref = res.history["force_N"][1:], ref.history["force_N"][1:]
    assert np.max(np.abs(f - f_ref) / np.abs(f_ref)) <= 1e-12


def test_joint_local_solve_runs_the_seed_scene_as_the_nested_one():
    """A scene's Anand law picks its local solve by size (``Anand.for_points``: the nested
    bracketed solve alone below JOINT_MIN_POINTS Gauss points, as on this 10 x 10 mesh;
    Newton on both equations first from there).  Reference: the nested solve's run.  The
    joint solve forced on the same scene gives the same force history and unknowns to
    1e-10 relative (both solve the return map to rtol 1e-13 and Newton to 1e-10)."""
    from jaxform.materials.anand import JOINT_MIN_POINTS

    sc, ref = seed_run()
    law = sc.model.law
    assert not law.joint and law.for_points(JOINT_MIN_POINTS).joint
    res = simulate(replace(sc, model=replace(sc.model, law=replace(law, joint=True))))
    f, f_ref = res.history["force_N"][1:], ref.history["force_N"][1:]
    assert np.max(np.abs(f - f_ref) / np.abs(f_ref)) <= 1e-10
    u, u_ref = res.fields["x"][-1], ref.fields["x"][-1]
    assert np.max(np.abs(u - u_ref)) <= 1e-10 * np.max(np.abs(u_ref))


def test_newton_quadratic_tail_on_seed_scene():
    """Quadratic tail: for 1e-7 < e_k < 1e-2 (e = ||R||/F; below 1e-7, e_k^2 is under the
    round-off floor ~1e-14), e_{k+1} <= 10 e_k^2.  Measured on the seed scene: the ratios
    e_{k+1}/e_k^2 lie between 1e-4 and ~1, e.g. 44 -> 0.48 -> 6.5e-4 -> 4.8e-11."""
    _, res = newton_seed_run()
    ratios = []
    for hist in res.newton_histories:
        e = hist[np.isfinite(hist)]
        for a, b in zip(e[:-1], e[1:]):
            if 1e-7 < a < 1e-2:
                ratios.append(b / a**2)
    assert len(ratios) > 20
    assert max(ratios) <= 10.0, max(ratios)
    assert res.history["newton_iterations"][1:].max() <= 6


def test_sparse_and_dense_backends_agree_on_seed_scene():
    """klujax (auto above 100 unknowns) and dense LU, both by full Newton (modified
    Newton's refreshes follow round-off): same history to 1e-10 relative."""
    sc, res = newton_seed_run()
    assert sc.linear.backend == "sparse"
    dense = simulate(scene("solver.linear=dense", "solver.newton=newton"))
    assert dense.scene.linear.backend == "dense"
    assert_same_history(dense, res, 1e-10)


def assert_same_history(res, ref, rtol):
    """Same force history and final unknowns to rtol relative, same Newton iterations."""
    f, f_ref = res.history["force_N"][1:], ref.history["force_N"][1:]
    assert np.max(np.abs(f - f_ref) / np.abs(f_ref)) <= rtol
    assert np.array_equal(res.history["newton_iterations"], ref.history["newton_iterations"])
    u, u_ref = res.fields["x"][-1], ref.fields["x"][-1]
    assert np.max(np.abs(u - u_ref)) <= rtol * np.max(np.abs(u_ref))


@pytest.mark.slow  # ~26 s; tests/test_linear.py checks this backend's solves in the default suite
def test_jax_sparse_backend_agrees_on_seed_scene():
    """jax.experimental.sparse.linalg.spsolve (the GPU sparse path; on CPU SciPy's spsolve
    through a callback) gives the same history as klujax to 1e-10 relative (full Newton:
    it keeps no factorization)."""
    sc, res = newton_seed_run()
    other = simulate(scene("solver.linear=jax-sparse"))
    assert other.scene.linear.backend == "jax-sparse"
    assert_same_history(other, res, 1e-10)


def test_cutback_completes_a_step_made_to_fail():
    """dt = 10 s with 3 Newton iterations allowed: steps fail, are halved, the run completes."""
    sc = scene(
        "mesh.nr=3",
        "mesh.nz=3",
        "time.dt_s=10.0",
        "solver.max_newton_iterations=3",
        "solver.chunk_steps=4",
        "die.reduction=0.3",
    )
    res = simulate(sc)
    assert res.history["cutbacks"].sum() > 0
    assert abs(res.history["stroke_mm"][-1] - 0.3 * 7.5) <= 1e-12


def test_a_large_step_from_rest_converges_at_its_size_through_a_probe():
    """A step from rest first solves a quarter of itself (time.first_step_probe) and takes
    the probe's rate as its predictor.  On 10 x 10 at dt = 16 s (16 % strain in one step,
    hundreds of times the yield strain: Newton starts from a far elastic overshoot) the
    step from rest fails without the probe and is cut back; with it the step converges at
    16 s, to the force of a 3 x 3 mesh's step solved from rest without a probe (frictionless
    upsetting is homogeneous: the same force on any mesh, 1e-9 relative, both solves
    converge to rtol 1e-10)."""
    one_step = ("time.dt_s=16.0", "die.reduction=0.16", "output.fields=false")
    plain = simulate(scene(*one_step, "time.first_step_probe=0"))
    assert plain.history["cutbacks"][1] >= 1
    probed = simulate(scene(*one_step))
    h = probed.history
    assert h["cutbacks"][1] == 0 and np.array_equal(h["time_s"], [0.0, 16.0])
    coarse = simulate(scene(*one_step, "time.first_step_probe=0", "mesh.nr=3", "mesh.nz=3"))
    assert coarse.history["cutbacks"][1] == 0
    np.testing.assert_allclose(h["force_N"][1], coarse.history["force_N"][1], rtol=1e-9)


def test_klujax_raises_on_a_singular_matrix():
    """The assumption the host loop's singular cutback rests on: klujax raises a
    JaxRuntimeError naming a singular matrix instead of returning a status."""
    import klujax
    from jax.errors import JaxRuntimeError

    rows, cols = jnp.array([0, 1, 1]), jnp.array([0, 0, 1])
    with pytest.raises(JaxRuntimeError, match="singular"):
        klujax.solve(rows, cols, jnp.array([1.0, 2.0, 0.0]), jnp.ones(2))


def _singular_after(t_from: float, h_above: float, until: float = np.inf):
    """run_chunk, raising as klujax does on a singular Jacobian for every attempt from
    t_from <= t < until with a step larger than h_above."""
    from jax.errors import JaxRuntimeError

    from jaxform import chunks

    real = chunks._run_chunk

    def fake(stepper, state, control, inp, idx, n, fac):
        t = float(state.t)
        if t_from - 1e-9 <= t < until and float(control.h) > h_above:
            raise JaxRuntimeError("INVALID_ARGUMENT: klu_factor/z_factor failed (singular matrix?)")
        return real(stepper, state, control, inp, idx, n, fac)

    return fake


def test_singular_jacobian_cuts_back_like_any_failed_step(monkeypatch):
    """A step whose Jacobian the linear solver finds singular (at dt = 1 and 0.5 s from
    t = 2 s) is retried with the step halved and converges at 0.25 s; the run goes on
    and ends at its end time.  With the step singular at every size the run stops after
    all cutbacks, naming the cause."""
    from jaxform import chunks

    sc = scene("mesh.nr=3", "mesh.nz=3", "die.reduction=0.05", "solver.chunk_steps=1")
    monkeypatch.setattr(chunks, "_run_chunk", _singular_after(2.0, 0.3, until=2.1))
    h = simulate(sc).history
    k = int(np.argmin(np.abs(h["time_s"] - 2.25)))
    assert h["time_s"][k] == pytest.approx(2.25) and h["dt_s"][k] == pytest.approx(0.25)
    assert h["cutbacks"][k] == 2 and h["cutbacks"].sum() == 2
    assert h["time_s"][-1] == pytest.approx(sc.t_end, rel=1e-12)
    monkeypatch.setattr(chunks, "_run_chunk", _singular_after(2.0, 0.0))
    with pytest.raises(SimulationError, match="step 3 .*failed after 7 attempts.*singular") as e:
        simulate(sc)
    assert e.value.result.history["time_s"][-1] == pytest.approx(2.0)


def test_a_stopped_run_writes_the_series_of_its_converged_rows(tmp_path, monkeypatch):
    """``jaxform run`` writes the ParaView series row by row; a run that stops (the step
    from t = 2 s singular at every size, as above) ends with FAILED.txt, and the series
    indexes exactly the converged rows (t = 0, 1, 2 s), each with its file."""
    from jaxform import chunks

    monkeypatch.setattr(chunks, "_run_chunk", _singular_after(2.0, 0.0))
    over = ["mesh.nr=3", "mesh.nz=3", "die.reduction=0.05", "solver.chunk_steps=1",
            "output.fields=true", "output.plots=false"]  # fmt: skip
    args = ["run", "configs/upsetting_seed.toml", "--out", str(tmp_path)]
    assert main(args + [a for o in over for a in ("--set", o)]) == 1
    assert "step 3" in (tmp_path / "FAILED.txt").read_text()
    times = np.atleast_1d(read_csv(tmp_path / "history.csv")["time_s"])
    np.testing.assert_allclose(times, [0.0, 1.0, 2.0], rtol=1e-12)
    pvd = (tmp_path / "fields.pvd").read_text()
    listed = re.findall(r'timestep="([^"]+)" part="0" file="([^"]+)"', pvd)
    assert [(float(t), f) for t, f in listed] == [
        (float(t), f"fields/step_{k:05d}.vtu") for k, t in enumerate(times)
    ]
    written = sorted(p.name for p in (tmp_path / "fields").glob("step_*.vtu"))
    assert written == [f"step_{k:05d}.vtu" for k in range(3)]


def test_impossible_scene_stops_with_message_and_state(tmp_path):
    code = main(
        [
            "run",
            "configs/upsetting_seed.toml",
            "--out",
            str(tmp_path),
            "--set",
            "mesh.nr=3",
            "--set",
            "mesh.nz=3",
            "--set",
            "time.dt_s=20.0",
            "--set",
            "solver.max_newton_iterations=3",
            "--set",
            "solver.max_cutbacks=0",
            "--set",
            "solver.smallest_step_continuations=0",
            "--set",
            "solver.chunk_steps=4",
            "--set",
            "output.fields=false",
            "--set",
            "output.plots=false",
        ]
    )
    assert code == 1
    msg = (tmp_path / "FAILED.txt").read_text()
    assert "step 1" in msg and "Newton did not converge" in msg and "target time 20 s" in msg
    # how the solve went: 3 iterations (solver.max_newton_iterations), its residual fell
    # but stayed above solver.rtol = 1e-10 (0.893 -> 0.0214 when written)
    went = re.search(r"went (\S+) -> (\S+) in (\d+) iterations, least (\S+);", msg)
    first, last, n, least = float(went[1]), float(went[2]), int(went[3]), float(went[4])
    assert n == 3 and 1e-10 < least <= last < first, msg
    table = read_csv(tmp_path / "history.csv")
    assert np.atleast_1d(table["time_s"])[-1] == 0.0  # last converged state: the initial one
    with pytest.raises(SimulationError):
        simulate(
            scene(
                "mesh.nr=3",
                "mesh.nz=3",
                "time.dt_s=20.0",
                "solver.chunk_steps=4",
                "solver.max_newton_iterations=3",
                "solver.max_cutbacks=0",
                "solver.smallest_step_continuations=0",
            )
        )


def test_newton_goes_on_at_the_smallest_step():
    """At the smallest step a Newton solve that runs out of iterations goes on from its last
    iterate (solver.smallest_step_continuations): 3 iterations per solve, no cutback, a
    stop without continuations; with 6 of them (21 iterations) the run ends, on the same
    root as one solve of 25 iterations (relative force difference <= 1e-9: both converge to
    rtol = 1e-10 of the force scale), its continuations counted as failed attempts."""
    base = ("mesh.nr=3", "mesh.nz=3", "time.dt_s=5.0", "solver.chunk_steps=4",
            "solver.max_cutbacks=0", "output.fields=false")  # fmt: skip
    with pytest.raises(SimulationError, match="Newton did not converge"):
        simulate(scene(*base, "solver.max_newton_iterations=3",
                       "solver.smallest_step_continuations=0"))  # fmt: skip
    # the reference: one solve of 25 iterations (solver.max_newton_iterations' default)
    # with the default cutbacks and chunks, which it does not use (no step fails: the
    # same steps), so it is the program of homogeneous_run("q1q1")
    ref = simulate(scene("mesh.nr=3", "mesh.nz=3", "time.dt_s=5.0", "output.fields=false"))
    assert ref.history["cutbacks"].max() == 0
    res = simulate(scene(*base, "solver.max_newton_iterations=3",
                         "solver.smallest_step_continuations=6"))  # fmt: skip
    f_ref, f = ref.history["force_N"][1:], res.history["force_N"][1:]
    np.testing.assert_allclose(f, f_ref, rtol=1e-9)
    assert res.history["cutbacks"].max() >= 1  # some step needed a continuation
    assert np.array_equal(res.history["time_s"], ref.history["time_s"])


def test_bad_config_is_rejected_before_compiling(capsys, tmp_path):
    for override, key in (
        ("billet.height_mm=-1", "billet.height_mm"),
        ("die.reduction=1.0", "die.reduction"),
        ("mesh.nr=0", "mesh.nr"),
        ("mesh.foo=1", "mesh.foo"),
    ):
        assert (
            main(["run", "configs/upsetting_seed.toml", "--set", override, "--out", str(tmp_path)])
            == 2
        )
        assert key in capsys.readouterr().err


def test_seed_scene_outputs(tmp_path):
    """The CLI's outputs for the seed scene: history columns, resolved config, fields, PNGs."""
    from jaxform.driver import write_outputs

    _, res = seed_run()
    write_outputs(
        tmp_path,
        replace(
            res,
            scene=replace(
                res.scene,
                settings=replace(
                    res.scene.settings,
                    output=replace(res.scene.settings.output, fields=True, plots=True),
                ),
            ),
        ),
    )
    table = read_csv(tmp_path / "history.csv")
    for col in ("time_s", "stroke_mm", "force_N", "newton_iterations"):
        assert col in table
    assert abs(table["stroke_mm"][-1] - 0.563 * 7.5) <= 1e-9
    assert table["force_N"][-1] > table["force_N"][1] > 0
    assert (tmp_path / "config.toml").exists() and (tmp_path / "fields.pvd").exists()
    assert len(list((tmp_path / "fields").glob("*.vtu"))) == 58
    for png in ("force_stroke.png", "deformed_mesh.png", "eqps.png", "contact_profile.png"):
        assert (tmp_path / png).stat().st_size > 5000


@pytest.mark.parametrize("element", ["q1q1", "q1p0"])
def test_compact_point_tangent_equals_the_plain_derivatives(element, monkeypatch):
    """formulations.planar_point_update (the material point differentiated in the five
    components of f, then mapped through) against jacfwd/grad through the plain update, on
    one plastically flowing Anand element (axisymmetric, distorted): the element Jacobian
    in the dofs, and the gradients of a scalar of (R, new Gauss state) with respect to the
    material parameters, the reference coordinates and dt (and in the parameters alone,
    where f is constant and its tangent a symbolic zero).  Same derivatives computed in
    another order: equal to 1e-12 relative (measured ~3e-16)."""
    from jaxform import formulations as fm
    from jaxform.formulations import formulation, initial_gauss_state
    from jaxform.materials.presets import load_material

    law, params = load_material("al1100_673K")
    form = formulation(element, axisymmetric=True)
    x_ref = jnp.array([[1.0, 0.0], [2.1, 0.2], [2.0, 1.1], [0.9, 0.9]])
    rng = np.random.default_rng(3)
    strain = np.column_stack([0.02 * x_ref[:, 0], -0.04 * x_ref[:, 1]])
    dofs = np.zeros((4, form.n_fields))
    dofs[:, :2] = strain + 1e-3 * rng.standard_normal((4, 2))
    if form.n_fields == 3:
        dofs[:, 2] = 10.0 + rng.standard_normal(4)
    g0 = initial_gauss_state(law, params, 1)
    gstate = jax.tree_util.tree_map(lambda a: a[0], g0)

    def residual(d, p, xr, dt):
        r, gnew, code = form.residual(law, p, dt, xr, d.reshape(4, -1), gstate)
        return r.ravel(), gnew, code

    def scalar(p, xr, dt):
        r, gnew, _ = residual(jnp.asarray(dofs).ravel(), p, xr, dt)
        return jnp.sum(r**2) + sum(jnp.sum(a**2) for a in jax.tree_util.tree_leaves(gnew))

    def derivatives():  # jitted afresh (so traced afresh) for each implementation
        @jax.jit
        def all_of_them(d, p, xr, dt):
            jac = jax.jacfwd(lambda dd: residual(dd, p, xr, dt)[0])(d)
            grads = jax.grad(scalar, argnums=(0, 1, 2))(p, xr, dt)
            g_p = jax.grad(lambda q: scalar(q, x_ref, 1.0))(p)  # f constant: df symbolic zero
            return (
                [jac] + jax.tree_util.tree_leaves(grads) + jax.tree_util.tree_leaves(g_p),
                residual(d, p, xr, dt)[2],
            )

        out, code = all_of_them(jnp.asarray(dofs).ravel(), params, x_ref, jnp.asarray(1.0))
        return out, int(code)

    compact, code = derivatives()
    monkeypatch.setattr(
        fm,
        "planar_point_update",
        lambda lw, alpha, f, s, p, dt, sol=None: fm._point(lw, alpha, f, s, p, dt, sol),
    )
    plain, code_plain = derivatives()
    assert code == code_plain == OK
    errs = [
        float(jnp.max(jnp.abs(a - b)) / jnp.max(jnp.abs(b)))
        for a, b in zip(compact, plain)
        if float(jnp.max(jnp.abs(b))) > 0.0
    ]
    assert len(errs) >= 8 and max(errs) <= 1e-12, errs
