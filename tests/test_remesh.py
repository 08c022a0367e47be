"""Remeshing: gmsh quad meshes of a deformed section, the state transfer, remeshed runs.

References: the polygon's exact area and Pappus volume (the new mesh keeps the boundary
polygon, so the material volume is unchanged to round-off); isoparametric quads and a
linear least-squares patch fit reproduce linear fields exactly; bilinear interpolation of
a smooth field converges as h^2 (the finest observed order within 0.1 of 2); frictionless
upsetting is a homogeneous deformation, so its force does not depend on the mesh (remeshed and
unremeshed runs agree to 1e-6 relative, the issue asks 0.1 %).
"""

from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from experiment_loader import experiment

import jaxform
from jaxform.config import ConfigError, check_gradient_run, load_config
from jaxform.contact import Frictionless
from jaxform.dies import RigidDie
from jaxform.geometry import min_quality, nearest_on_segments, polygon_measure
from jaxform.mesh import billet_quarter, boundary_polygon, polygon_quads
from jaxform.section_mesh import simplify
from jaxform.solver import ModifiedNewton
from jaxform.transfer import Transfer, gauss_points, gauss_to_nodes
from jaxform.triggers import corner_depth_ratio, fold_angle_deg


def _barrel(n_side=11):
    """A barrelled quarter section (axis, mid-plane, bulging side, top) and its labels."""
    r, h = 4.0, 2.5
    z = np.linspace(0.0, h, n_side)
    side = np.column_stack([r + 0.5 * (1 - (z / h) ** 2), z])
    top = np.column_stack([np.linspace(r, 0.0, 9)[1:], np.full(8, h)])
    axis = np.column_stack([np.zeros(4), np.linspace(h, 0.0, 6)[1:-1]])
    bottom = np.column_stack([np.linspace(0.0, r + 0.5, 10)[:-1], np.zeros(9)])
    labels = ["symmetry"] * 9 + ["side"] * (n_side - 1) + ["top"] * 8 + ["axis"] * 5
    return np.vstack([bottom, side, top, axis]), labels


def test_polygon_quads_keeps_the_boundary_and_names_the_sets():
    """All quads, counter-clockwise, every vertex a node, the polygon's volume exact
    (1e-12), each edge's label a facet set whose nodes lie on that edge."""
    pts, labels = _barrel()
    mesh = polygon_quads(pts, labels, np.full(len(pts), 0.3))
    assert mesh.elements.shape[1] == 4
    assert polygon_measure(mesh.coords[mesh.elements], False).min() > 0.0
    assert min_quality(mesh.coords, mesh.elements) > 0.3
    for axi in (True, False):
        v_mesh = polygon_measure(mesh.coords[mesh.elements], axi).sum()
        v_poly = polygon_measure(pts[None], axi)[0]
        assert abs(v_mesh / v_poly - 1.0) < 1e-12
    d = np.min(np.linalg.norm(mesh.coords[:, None] - pts[None], axis=2), axis=0)
    assert d.max() < 1e-12  # every polygon vertex is a node
    c = mesh.coords
    assert np.allclose(c[mesh.node_sets["axis"], 0], 0.0)
    assert np.allclose(c[mesh.node_sets["symmetry"], 1], 0.0)
    assert np.allclose(c[mesh.node_sets["top"], 1], 2.5)
    assert set(mesh.facet_sets) == {"axis", "symmetry", "top", "side"}


def test_boundary_polygon_and_simplify_of_a_structured_section():
    """The boundary of a 4 x 3 billet section is one counter-clockwise loop of 14 nodes;
    the straight sides simplify to the 4 corners, and a bulged side keeps its vertices."""
    mesh = billet_quarter(2.0, 1.5, 4, 3)
    pts, labels, nodes = boundary_polygon(mesh, mesh.coords)
    assert len(pts) == 14 and polygon_measure(pts[None], False)[0] == pytest.approx(3.0)
    kept, kept_labels = simplify(pts, labels, 1e-9)
    assert len(kept) == 4 and sorted(kept_labels) == ["axis", "side", "symmetry", "top"]
    bulged = mesh.coords.copy()
    side = mesh.node_sets["side"]
    bulged[side, 0] += 0.1 * np.sin(np.pi * bulged[side, 1] / 3.0)
    pts, labels, _ = boundary_polygon(mesh, bulged)
    kept, _ = simplify(pts, labels, 1e-9)
    assert len(kept) == 4 + 2  # the corners and the two bulged side nodes


def _meshes():
    """An old structured mesh and a new gmsh mesh of the same rectangle [0, 2] x [0, 1]."""
    old = billet_quarter(2.0, 1.0, 8, 4)
    pts, labels, _ = boundary_polygon(old, old.coords)
    kept, kept_labels = simplify(pts, labels, 1e-9)
    new = polygon_quads(pts[kept], kept_labels, np.full(len(kept), 0.17))
    return old, new


def test_transfer_between_meshes_is_exact_for_linear_fields():
    """A linear Gauss field and a linear nodal field carried from a structured mesh to an
    unstructured gmsh mesh of the same section: exact to 1e-12."""
    old, new = _meshes()

    def f(p):
        return 1.5 - 2.0 * p[..., 0] + 0.7 * p[..., 1]

    move = Transfer(old.coords, old.elements, new.coords, new.elements)
    gp_old, gp_new = gauss_points(old.coords, old.elements), gauss_points(new.coords, new.elements)
    assert np.max(np.abs(move.gauss(f(gp_old)) - f(gp_new))) < 1e-12
    assert np.max(np.abs(move.nodal(f(old.coords)) - f(new.coords))) < 1e-12


def test_transfer_of_a_smooth_field_converges_at_second_order():
    """f = sin(2 r) cos(3 z) from Gauss points of n x n/2 grids (n = 16, 32, 64) to the
    Gauss points of a fixed fine gmsh mesh: the max error falls as h^2 (observed orders
    1.80 and 1.98: both above 1.7, the finer within 0.1 of 2)."""
    fine = polygon_quads(
        np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]]), ["a"] * 4, np.full(4, 0.03)
    )
    gp_new = gauss_points(fine.coords, fine.elements)

    def f(p):
        return np.sin(2.0 * p[..., 0]) * np.cos(3.0 * p[..., 1])

    errors = []
    for n in (16, 32, 64):
        old = billet_quarter(2.0, 1.0, n, n // 2)
        move = Transfer(old.coords, old.elements, fine.coords, fine.elements)
        got = move.gauss(f(gauss_points(old.coords, old.elements)))
        errors.append(np.max(np.abs(got - f(gp_new))))
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert orders.min() > 1.7 and abs(orders[-1] - 2.0) < 0.1, (errors, orders)


def test_patch_recovery_keeps_a_nonnegative_field_nonnegative():
    """A field that is zero except at one Gauss point (a strain spike): recovered nodal
    values stay >= 0 and within the spike's value."""
    old = billet_quarter(2.0, 1.0, 4, 2)
    v = np.zeros((old.n_elements, 4))
    v[3, 2] = 1.0
    nodal = gauss_to_nodes(v, old.coords, old.elements)
    assert nodal.min() >= 0.0 and nodal.max() <= 1.0 + 1e-12


SEED = "configs/upsetting_seed.toml"
QUIET = ["output.plots=false", "output.fields=false"]


def test_forced_remeshes_leave_frictionless_upsetting_unchanged():
    """Seed (frictionless) on 4 x 4 to 15 % with a new mesh every 5 steps (2 remeshes)
    against the run without: forces within 1e-6 relative (homogeneous deformation: any
    mesh carries it exactly), volume kept to 1e-12 per remesh, eqps integral kept to 1e-9,
    the history marks the two remeshes."""
    over = QUIET + ["mesh.nr=4", "mesh.nz=4", "die.reduction=0.15"]
    plain = jaxform.run(SEED, over)
    res = jaxform.run(SEED, over + ["remesh.every_steps=5"])
    h0, h1 = plain.history, res.history
    assert len(res.remeshes) == 2 and list(np.nonzero(h1["remeshed"])[0]) == [5, 10]
    # the two new meshes fit one capacity bucket: at most one step program besides the first
    assert res.step_programs <= 2
    assert np.allclose(h1["force_N"], h0["force_N"], rtol=1e-6)
    for rep in res.remeshes:
        assert abs(rep.volume_change) < 1e-12
        assert rep.eqps_integral_after == pytest.approx(rep.eqps_integral_before, rel=1e-9)
        assert rep.quality_after > 0.5
    assert len(res.segments) == 3 and res.scene_at(6) is res.segments[1].scene
    assert res.final_scene.mesh.n_elements != plain.scene.mesh.n_elements
    # the fields of each row live on its own mesh
    assert len(res.fields["x"][-1]) == res.final_scene.model.layout.n_dofs
    assert all(rep.trigger == "steps" for rep in res.remeshes)
    # every 0.4 mm of stroke (1.125 mm in all): after the steps that reach 0.4 and 0.8 mm
    # past the last remesh
    by_stroke = jaxform.run(SEED, over + ["remesh.every_stroke_mm=0.4"])
    h2 = by_stroke.history
    rows = np.nonzero(h2["remeshed"])[0]
    assert len(rows) == 2 and all(rep.trigger == "stroke" for rep in by_stroke.remeshes)
    assert h2["stroke_mm"][rows[0]] >= 0.4 > h2["stroke_mm"][rows[0] - 1]
    assert h2["stroke_mm"][rows[1]] - h2["stroke_mm"][rows[0]] >= 0.4
    assert h2["stroke_mm"][rows[1] - 1] - h2["stroke_mm"][rows[0]] < 0.4
    assert np.allclose(h2["force_N"], h0["force_N"], rtol=1e-6)


def test_a_run_can_start_on_the_remeshers_own_mesh():
    """remesh.from_start: the seed (frictionless, homogeneous: any mesh carries it
    exactly) on 4 x 4 to 15 % starts on a gmsh mesh of its section and remeshes every 5
    steps; its forces equal the structured run's to 1e-6 relative and the start mesh holds
    the structured mesh's volume to 1e-12.  The flash scene's start mesh is fine (die_size_ratio x
    the bulk size, to 30 %) along the flange face that touches the billet at t = 0 and
    coarse (the bulk size, to 30 %) along the top under the hub recess, which does not."""
    over = QUIET + ["mesh.nr=4", "mesh.nz=4", "die.reduction=0.15"]
    plain = jaxform.run(SEED, over)
    res = jaxform.run(SEED, over + ["remesh.every_steps=5", "remesh.from_start=true"])
    start = res.segments[0].scene
    assert start.grid is None and start.mesh.n_nodes != plain.scene.mesh.n_nodes

    def volume(mesh):
        return polygon_measure(np.asarray(mesh.coords)[mesh.elements], True).sum()

    assert volume(start.mesh) == pytest.approx(volume(plain.scene.mesh), rel=1e-12)
    assert np.allclose(res.history["force_N"], plain.history["force_N"], rtol=1e-6)
    from jaxform.scenes import build_scene

    scene = build_scene(load_config("configs/closed_die_flash.toml", ["remesh.from_start=true"]))
    c, top = np.asarray(scene.mesh.coords), scene.mesh.node_sets["top"]
    rt = np.sort(c[top, 0])
    gaps = np.diff(rt)
    mid = 0.5 * (rt[1:] + rt[:-1])
    fine, bulk = 0.35 * 0.35, 0.35  # die_size_ratio x element_size_mm, element_size_mm
    assert np.all(np.abs(gaps[(mid > 3.2) & (mid < 4.8)] / fine - 1) < 0.3)
    assert np.all(np.abs(gaps[mid < 1.5] / bulk - 1) < 0.3)
    with pytest.raises(ConfigError, match="remesh.from_start"):
        load_config(SEED, ["remesh.from_start=true"])


def test_trigger_measures_of_known_geometry():
    """A die corner (arc of radius 0.2 mm rounding a flat punch's edge, lowest point at z =
    1 - travel) against a horizontal facet 0.6 mm long at z = 0.95: depth 0.05 mm after
    0.1 mm of travel, ratio 0.05 / 0.6 (to 1e-12; 0 before it touches).  A free-surface
    fold whose facets meet at the air angle atan(0.2) = 11.31 deg (to 1e-12), 180 deg once
    the vertex touches the die."""
    die = RigidDie(
        points=jnp.array([[0.0, 1.0], [2.0, 1.0], [2.0, 3.0]]),
        path_time_s=jnp.array([0.0, 1.0]),
        path_travel_mm=jnp.array([0.0, 0.1]),
        friction=Frictionless(),
        corner_radius=jnp.asarray(0.2),
    )
    # each measure compiled as one program, as inside a chunk (eagerly, each of their
    # operations compiled a program of its own: 183 programs, 12 s on a 2-core CPU)
    idx = SimpleNamespace(contact_nodes=jnp.arange(2), contact_facets=jnp.array([[0, 1]]))
    depth = jax.jit(lambda d, p, t: corner_depth_ratio(d, p, idx, t))
    pos = jnp.array([[2.1, 0.95], [1.5, 0.95]])  # walked with the material below (left)
    assert float(depth(die, pos, 1.0)) == pytest.approx(0.05 / 0.6, abs=1e-12)
    assert float(depth(die, pos, 0.0)) == 0.0
    idx3 = SimpleNamespace(contact_nodes=jnp.arange(3), contact_facets=jnp.array([[0, 1], [1, 2]]))
    fold = jax.jit(lambda p, s: fold_angle_deg(p, idx3, s))
    pos = jnp.array([[0.0, 0.0], [1.0, 0.0], [0.0, -0.2]])
    open_ = np.zeros(3, np.int32)
    angle = float(fold(pos, open_))
    assert angle == pytest.approx(np.degrees(np.arctan(0.2)), abs=1e-12)
    open_[1] = 1
    assert float(fold(pos, open_)) == 180.0


def test_remesh_config_is_checked():
    """[remesh] with rezoning, on a membrane, and with a design objective that reads the
    initial mesh: one line each."""
    with pytest.raises(ConfigError, match="choose one"):
        load_config(SEED, ["remesh.quality_below=0.3", "mesh.rezone_quality=0.2"])
    with pytest.raises(ConfigError, match=r"\[membrane\] scene cannot be remeshed"):
        load_config("configs/cooks_membrane.toml", ["remesh.every_steps=3"])
    cfg = load_config(SEED, ["remesh.every_steps=3", "design.objective=eqps_spread"])
    with pytest.raises(ConfigError, match="reads the initial mesh"):
        check_gradient_run(cfg)
    with pytest.raises(ConfigError, match="remesh.die_size_ratio"):
        load_config(SEED, ["remesh.die_size_ratio=0"])


@pytest.mark.slow
def test_ring_with_high_friction_runs_to_the_end_with_remeshing():
    """6:3:2 ring, m = 0.5, q1q1 with remesh.quality_below = 0.4 on the shipped 12 x 6 mesh
    and on 24 x 12: both reach 50 %, volume kept to 1e-10 per remesh, the inner-diameter
    changes agree within 1 percentage point (the issue's mesh check) and lie within 10
    points of Avitzur's upper bound (-27.4 %; its field has no barrel, so it reads less
    negative: experiments/ring_remesh.py)."""
    changes = []
    for nr, nz in ((12, 6), (24, 12)):
        over = QUIET + ["friction.m=0.5", f"mesh.nr={nr}", f"mesh.nz={nz}",
                        "remesh.quality_below=0.4"]  # fmt: skip
        res = jaxform.run("configs/ring_compression.toml", over)
        h = res.history
        assert h["stroke_mm"][-1] == pytest.approx(3.0)
        assert all(abs(r.volume_change) < 1e-10 for r in res.remeshes)
        changes.append(100.0 * (h["inner_diameter_mm"][-1] / 9.0 - 1.0))
    assert abs(changes[0] - changes[1]) < 1.0, changes
    assert all(-37.4 < c < -27.4 for c in changes), changes


def test_padding_to_a_bucket_is_inert_and_shared():
    """The seed on 4 x 4 and on 5 x 4 padded to one bucket: equal layouts and argument
    shapes (one compiled program serves both), and one step of the padded 4 x 4 scene
    equals the unpadded step (unknowns to 1e-10 relative, ghosts at rest).  Both by
    modified Newton, which ``step`` runs with a factorization of its own (it once passed
    none and failed on the first refresh)."""
    from jaxform.capacity import Bucket, padded
    from jaxform.config import typed
    from jaxform.scenes import build_scene
    from jaxform.simulation import init, step

    def scene(nr):
        overrides = [f"mesh.nr={nr}", "mesh.nz=4", "solver.newton=modified"]
        return build_scene(typed(load_config(SEED, QUIET + overrides)))

    a, b = scene(4), scene(5)
    bucket = Bucket(64, 24)
    pa, pb = padded(a, bucket), padded(b, bucket)
    assert pa.scene.model.layout == pb.scene.model.layout
    shapes = [
        jax.tree_util.tree_map(lambda v: np.shape(v), (p.scene.idx, p.scene.inputs))
        for p in (pa, pb)
    ]
    assert shapes[0] == shapes[1]
    state, control = init(a)
    plain, _, _ = step(a, state, control)
    big, _, _ = step(pa.scene, pa.state(state), control)
    back = pa.trim(big)
    assert a.newton.variant == pa.scene.newton.variant == ModifiedNewton(anderson_depth=3)
    x0, x1 = np.asarray(plain.x), np.asarray(back.x)
    assert np.max(np.abs(x1 - x0)) <= 1e-10 * np.max(np.abs(x0))
    lay = pa.scene.model.layout
    ghosts = np.asarray(lay.nodal(big.x))[a.model.layout.n_nodes :]
    assert np.all(ghosts == 0.0)
    assert np.allclose(np.asarray(back.gauss.mat.stress), np.asarray(plain.gauss.mat.stress))


def test_a_gradient_replay_pads_to_buckets_twice_as_coarse():
    """Reference: the grids by hand.  The forward run's node capacities grow by 1.25
    (64, 80, 96, 128, 160, 192, 240, 304, ...), a replay's by 2 (64, 128, 256, 512, 1024),
    contacts from 16 (16, 32, 64, 128): the two-stage disk's finisher meshes of 250 - 865
    nodes fall in 2 node capacities instead of 6 (each with room for 8 ghosts, 2 ghost
    candidates)."""
    from types import SimpleNamespace

    from jaxform.capacity import Bucket, coarse_bucket, grid_value

    assert [grid_value(n, 64) for n in (65, 81, 97, 249)] == [80, 96, 128, 304]
    assert [grid_value(n, 64, 2.0) for n in (64, 65, 129, 258, 520, 873)] == [
        64, 128, 256, 512, 1024, 1024]  # fmt: skip

    def scene(nodes, contacts):
        layout = SimpleNamespace(n_nodes=nodes, n_contact=contacts)
        return SimpleNamespace(model=SimpleNamespace(layout=layout))

    assert coarse_bucket(scene(250, 40)) == Bucket(512, 64)
    assert coarse_bucket(scene(120, 14)) == Bucket(128, 16)
    fine = {grid_value(n + 8, 64) for n in range(250, 866)}
    coarse = {coarse_bucket(scene(n, 40)).nodes for n in range(250, 866)}
    assert len(fine) == 6 and coarse == {512, 1024}


def test_ghost_nodes_sit_where_the_die_leaves_them_open():
    """The closed die's cavity reaches down beside the section, where the ghost square
    once sat inside the die (its candidates closed, their multipliers absent from every
    equation: a singular Jacobian).  The ghosts now sit where the die's gap exceeds 1 mm
    all the run, and the padded Jacobian at the first step has full rank."""
    from jaxform.capacity import padded
    from jaxform.rezone import gap_function
    from jaxform.scenes import build_scene
    from jaxform.simulation import init
    from jaxform.stepping import step_context

    over = QUIET + ["mesh.nr=4", "mesh.nz=4", "mesh.rezone_quality=0", "die.corner_contact=false"]
    sc = build_scene(load_config("configs/closed_die.toml", over))
    pd = padded(sc)
    ghosts = np.asarray(pd.scene.inputs.coords)[sc.model.layout.n_nodes :]
    for t in (0.0, 0.5 * sc.t_end, sc.t_end):
        assert np.all(gap_function(sc.inputs.die, t)(ghosts)[0] > 1.0)
    st = pd.state(init(sc)[0])
    s = pd.scene
    vals = jax.jit(s.model.residual_and_jacobian)(
        st.x, step_context(s.model, st, s.inputs, s.idx, 0.01, 0.01)
    )[1]
    n = s.model.layout.n_dofs
    jac = np.zeros((n, n))
    jac[np.asarray(s.idx.rows), np.asarray(s.idx.cols)] = np.asarray(vals)
    assert np.linalg.matrix_rank(jac) == n


def test_fold_angle_of_known_wedges():
    """The seed section on 2 x 2 (R = 2.5 mm, flat die on the top face): no fold as built
    (180); the top face's middle node pulled 0.1 mm off the die between two touching nodes
    is a pocket of angle atan(0.1 / half its length along the surface, hypot(1.25, 0.1))
    (1e-9); an inward
    crease of the side (mid node pulled in by a = 4 h) gives the air wedge 2 atan(1/4) =
    28.07 deg (1e-9) at that node; their depths are the pocket's length along the
    surface and the crease's shorter flank (here one edge each: the side's corner and
    the mid-plane end them) (1e-12).  The fold list reports each run of rows below
    output.lap_angle_deg at one place once, with its stroke and place; the lap list only
    the wedge folds (wedge_* columns) that persist to the run's end, and a fold that
    moves farther than 0.1 mm plus twice the stroke between two rows is another one."""
    from jaxform.config import typed
    from jaxform.laps import fold_angle, laps
    from jaxform.scenes import build_scene

    scene = build_scene(typed(load_config(SEED, QUIET + ["mesh.nr=2", "mesh.nz=2"])))
    pos = np.asarray(scene.inputs.coords).copy()
    r, h = pos[:, 0].max(), pos[:, 1].max()
    assert fold_angle(scene, pos, 0.0)[0] == 180.0
    top = scene.mesh.node_sets["top"]
    mid_top = top[np.argsort(pos[top, 0])][1]
    pocket = pos.copy()
    pocket[mid_top, 1] -= 0.1
    angle, r_at, z_at, depth = fold_angle(scene, pocket, 0.0)
    assert angle == pytest.approx(np.degrees(np.arctan(0.1 / np.hypot(r / 2, 0.1))), abs=1e-9)
    assert depth == pytest.approx(2.0 * np.hypot(r / 2, 0.1), abs=1e-12)
    assert (r_at, z_at) == pytest.approx(tuple(pocket[mid_top]))
    side = scene.mesh.node_sets["side"]
    mid = side[np.argsort(pos[side, 1])][1]  # the side node at half of the half height
    crease = pos.copy()
    crease[mid, 0] = r - 4.0 * (h / 2)
    angle, r_at, z_at, depth = fold_angle(scene, crease, 0.0)
    assert angle == pytest.approx(np.degrees(2 * np.arctan(0.25)), abs=1e-9)
    edges = np.linalg.norm(crease[side] - crease[mid], axis=1)
    assert depth == pytest.approx(np.sort(edges)[1], abs=1e-12)  # [0] is the node itself
    assert (r_at, z_at) == pytest.approx(tuple(crease[mid]))
    hist = {
        "fold_angle_deg": np.array([90.0, 40.0, 8.0, 6.0, 12.0, 7.0]),
        "stroke_mm": np.arange(6.0),
        "fold_r_mm": np.ones(6),
        "fold_z_mm": np.zeros(6),
    }
    from jaxform.laps import folds

    every = folds(hist, 10.0)
    assert [(f["row"], f["last_row"], f["persists"]) for f in every] == [(2, 3, False),
                                                                       (5, 5, True)]  # fmt: skip
    assert every[0]["angle_deg"] == 8.0 and every[0]["end_angle_deg"] == 6.0
    wedges = {k.replace("fold_", "wedge_"): v for k, v in hist.items()}  # laps: wedges
    found = laps(wedges, 10.0)
    assert [f["row"] for f in found] == [5]
    assert laps(wedges, 0.0) == [] and laps(hist, 10.0) == []  # no wedge columns: no lap
    moved = dict(
        hist, fold_r_mm=np.array([1.0, 1.0, 1.0, 1.0, 1.0, 1.0]) + [0, 0, 0, 3.0, 3.0, 3.0]
    )
    moved["fold_angle_deg"] = np.array([90.0, 8.0, 8.0, 8.0, 8.0, 8.0])
    assert [(f["row"], f["persists"]) for f in folds(moved, 10.0)] == [(1, False), (3, True)]


def test_avitzur_upper_bound_reference():
    """The ring reference of experiments/ring_remesh.py: frictionless, Avitzur's field is
    homogeneous (R_n = 0), so the inner diameter grows by sqrt(T0 / T) - 1 = 41.421 % at
    50 % (to 0.01 points); friction turns the change negative and m = 1 lies below m = 0.5."""
    ring = experiment("ring_remesh")
    assert ring.avitzur_ring(0.0, steps=50)[-1, 1] == pytest.approx(100 * (2**0.5 - 1), abs=0.01)
    half, full = (ring.avitzur_ring(m, steps=20)[-1, 1] for m in (0.5, 1.0))
    assert full < half < 0.0


@pytest.mark.slow
def test_closed_die_with_flash_fills_and_forms_the_flash():
    """configs/closed_die_flash.toml to the end: die fill >= 0.999 of the part's cavity;
    no candidate inside a die by more than 1e-8 mm at any converged step; the material
    volume over the whole run (fourteen remeshes) kept to 1e-3; the flash grows to > 50 mm^3
    and the force at the end is >= 3 x the force at 90 % fill (the steep rise as the
    flash thins)."""
    from jaxform.postprocess import material_volume, positions
    from jaxform.rezone import gap_function

    res = jaxform.run("configs/closed_die_flash.toml", QUIET)
    h = res.history
    assert h["die_fill"][-1] >= 0.999
    assert h["flash_volume_mm3"][-1] > 50.0 and np.all(np.diff(h["flash_volume_mm3"]) >= -1e-6)
    k90 = int(np.argmax(h["die_fill"] >= 0.9))
    assert h["force_N"][-1] >= 3.0 * h["force_N"][k90]
    worst = 0.0
    for k in range(len(h["time_s"])):
        scene = res.scene_at(k)
        pos = positions(scene, res.fields["x"][k])[np.asarray(scene.idx.contact_nodes)]
        worst = min(worst, float(gap_function(scene.inputs.die, h["time_s"][k])(pos)[0].min()))
    assert worst >= -1e-8
    first, last = res.scene, res.final_scene
    v0 = material_volume(first, positions(first, res.fields["x"][0]))
    v1 = material_volume(last, positions(last, res.fields["x"][-1]))
    assert abs(v1 / v0 - 1.0) < 1e-3


def _corrupting_remesh(monkeypatch, how):
    """jaxform.adaptation.remesh, its new state changed by ``how`` (a failure to drive)."""
    import jaxform.adaptation as sim

    real = sim.remesh

    def remesh(scene, state, settings):
        done = real(scene, state, settings)
        return replace(done, state=how(done.state))

    monkeypatch.setattr(sim, "remesh", remesh)


def test_a_failure_on_the_first_step_after_a_remesh_keeps_the_last_state(monkeypatch, tmp_path):
    """The state a remesh hands over is made meaningless (NaN unknowns): the first step on
    each new mesh fails at every cutback.  The run goes back to the mesh before twice
    (GO_BACK_LIMIT; a step there each time, remeshed after it), then stops with
    SimulationError naming the remesh, the step, the time and the cause (no traceback, as
    the issue's closed dies ended: 'need at least one array to stack'); the result ends
    on the last converged state on the old mesh (7 steps, one segment, no remesh kept)
    and its outputs are written."""
    from jaxform.simulation import SimulationError

    _corrupting_remesh(monkeypatch, lambda s: replace(s, x=s.x * jnp.nan))
    # the settings of test_forced_remeshes_leave_frictionless_upsetting_unchanged, so the
    # run loads its compiled programs (the NaN step fails at every cutback, none converges)
    over = QUIET + ["mesh.nr=4", "mesh.nz=4", "die.reduction=0.15", "remesh.every_steps=5"]
    with pytest.raises(SimulationError) as err:
        jaxform.run(SEED, over, out_dir=tmp_path)
    msg = str(err.value)
    assert "\n" not in msg
    assert msg.startswith("the first step after the remesh at 7 s: ")
    assert "step 8" in msg and "the residual is not finite" in msg, msg
    res = err.value.result
    assert len(res.history["time_s"]) == 8 and len(res.segments) == 1 and not res.remeshes
    assert res.history["remeshed"].sum() == 0
    assert res.final_state.x.shape == (res.final_scene.model.layout.n_dofs,)
    assert float(res.final_state.t) == pytest.approx(res.history["time_s"][-1], abs=1e-12)
    assert np.all(np.isfinite(np.asarray(res.final_state.x)))
    lines = (tmp_path / "history.csv").read_text().splitlines()
    assert len(lines) == 1 + 8  # header and the eight rows (row 0 and seven steps)


def test_a_first_step_that_fails_below_the_run_step_is_tried_again_from_it(monkeypatch):
    """After each of the seed's two forced remeshes the run is set to a quarter of
    time.dt_s (as after cutbacks) and the first step on the new mesh is made to fail at
    any step below time.dt_s (as the two-stage disk's did from 6.6e-5 s down): the run
    tries that step again from time.dt_s and goes on to the end, each row after a remesh
    a step of time.dt_s, the forces those of the run without remeshes (1e-6 relative:
    frictionless, homogeneous).  A first step that fails from time.dt_s too on every new
    mesh sends the run back to the mesh before twice (a step there each time,
    GO_BACK_LIMIT) and then stops it with one line that says it was tried again, on the
    last converged state of the start mesh."""
    import jaxform.simulation as sim

    real_stepped, real_adapted = sim._stepped, sim._adapted
    refused = []

    def adapted(run, done, owned):
        new = real_adapted(run, done, owned)
        if not done.new_mesh:
            return new
        return replace(new, control=replace(new.control, h=0.25 * new.control.dt_max))

    def stepped(run, owned):
        if sim._on_new_mesh(run) and float(run.control.h) < float(run.control.dt_max):
            refused.append(float(run.control.h))
            return replace(run, failure="step (made to fail below time.dt_s)")
        return real_stepped(run, owned)

    monkeypatch.setattr(sim, "_adapted", adapted)
    monkeypatch.setattr(sim, "_stepped", stepped)
    over = QUIET + ["mesh.nr=4", "mesh.nz=4", "die.reduction=0.15"]
    res = jaxform.run(SEED, over + ["remesh.every_steps=5"])
    h = res.history
    dt = res.scene.dt
    assert len(refused) == 2 and all(r == pytest.approx(0.25 * dt) for r in refused)
    assert list(np.nonzero(h["remeshed"])[0]) == [5, 10]
    assert h["dt_s"][6] == pytest.approx(dt) and h["dt_s"][11] == pytest.approx(dt)
    monkeypatch.setattr(sim, "_stepped", real_stepped)
    plain = jaxform.run(SEED, over)
    assert np.allclose(h["force_N"], plain.history["force_N"], rtol=1e-6)

    def never(run, owned):
        if sim._on_new_mesh(run):
            return replace(run, failure="step (made to fail at any step)")
        return real_stepped(run, owned)

    monkeypatch.setattr(sim, "_stepped", never)
    with pytest.raises(sim.SimulationError) as err:
        jaxform.run(SEED, over + ["remesh.every_steps=5"])
    assert str(err.value).startswith(
        f"the first step after the remesh at 7 s: tried again from time.dt_s = {dt:g} s, step"
    ), str(err.value)
    # it went back to the start mesh GO_BACK_LIMIT times, a step there each time
    stopped = err.value.result
    assert len(stopped.segments) == 1 and stopped.history["remeshed"].sum() == 0
    assert len(stopped.history["time_s"]) == 1 + 5 + sim.GO_BACK_LIMIT


def _failing(sim, when):
    """jaxform.simulation._stepped, failing ("step (made to fail)") where ``when(run)``."""
    real = sim._stepped

    def stepped(run, owned):
        return replace(run, failure="step (made to fail)") if when(run) else real(run, owned)

    return stepped


def test_a_step_that_fails_goes_on_from_a_new_mesh_at_the_last_converged_state(monkeypatch):
    """The seed with remeshing on (a quality trigger that never fires) and its second
    chunk made to fail on the start mesh: the run remeshes at the last converged row
    (the remesh's trigger 'failed step', that row's `remeshed` column 1) and goes on to
    the end, its forces those of the run without remeshes (1e-6 relative: frictionless,
    homogeneous, as test_forced_remeshes_leave_frictionless_upsetting_unchanged).  Made
    to fail on every mesh after its first chunk, the run stops with one line naming the
    failure and that the new mesh did not help, on the last converged state of the start
    mesh (that remesh undone)."""
    import jaxform.simulation as sim

    real_stepped = sim._stepped
    on_start_mesh = _failing(sim, lambda run: len(run.segments) == 1 and len(run.rows) > 1)
    monkeypatch.setattr(sim, "_stepped", on_start_mesh)
    over = QUIET + ["mesh.nr=4", "mesh.nz=4", "die.reduction=0.15"]
    res = jaxform.run(SEED, over + ["remesh.quality_below=0.01"])
    h = res.history
    at = list(np.nonzero(h["remeshed"])[0])
    assert len(at) == 1 and at[0] >= 1 and len(res.segments) == 2
    assert [r.trigger for r in res.remeshes] == ["failed step"]
    monkeypatch.setattr(sim, "_stepped", real_stepped)
    plain = jaxform.run(SEED, over)
    assert len(h["force_N"]) == len(plain.history["force_N"])
    assert np.allclose(h["force_N"], plain.history["force_N"], rtol=1e-6)

    monkeypatch.setattr(sim, "_stepped", _failing(sim, lambda run: len(run.rows) > 1))
    with pytest.raises(sim.SimulationError) as err:
        jaxform.run(SEED, over + ["remesh.quality_below=0.01"])
    msg = str(err.value)
    assert "\n" not in msg
    assert msg.startswith("step (made to fail); a new mesh at the last converged time "), msg
    assert "did not help: its first step: " in msg
    stopped = err.value.result
    assert len(stopped.segments) == 1 and not stopped.remeshes
    assert stopped.history["remeshed"].sum() == 0 and len(stopped.history["time_s"]) == at[0] + 1


def test_a_new_mesh_whose_first_step_fails_goes_back_to_the_mesh_before(monkeypatch):
    """The seed with a remesh every 5 steps, the first step on its first new mesh made to
    fail (from time.dt_s too): the run goes back to the start mesh at row 5 (that remesh
    undone), takes a step there, remeshes after it (row 6) and goes on to the end, its
    forces those of the run without remeshes (1e-6 relative).  (Made to fail on every new
    mesh: test_a_first_step_that_fails_below_the_run_step_is_tried_again_from_it.)"""
    import jaxform.simulation as sim

    real_stepped = sim._stepped
    failed = []

    def first_new_mesh(run):
        if sim._on_new_mesh(run) and not failed:
            failed.append(len(run.rows))
            return True
        return False

    monkeypatch.setattr(sim, "_stepped", _failing(sim, first_new_mesh))
    over = QUIET + ["mesh.nr=4", "mesh.nz=4", "die.reduction=0.15"]
    res = jaxform.run(SEED, over + ["remesh.every_steps=5"])
    h = res.history
    assert failed == [6]  # the step to row 6 (at time.dt_s: not tried again)
    remeshed = list(np.nonzero(h["remeshed"])[0])
    assert remeshed[0] == 6 and len(res.segments) == len(remeshed) + 1
    monkeypatch.setattr(sim, "_stepped", real_stepped)
    plain = jaxform.run(SEED, over)
    assert np.allclose(h["force_N"], plain.history["force_N"], rtol=1e-6)


def test_an_error_between_chunks_is_one_line_with_the_last_state(monkeypatch):
    """Any error of the host loop between compiled chunks (here the remesh raising
    something no one planned for) ends the run with SimulationError naming the time,
    the stroke and the error, the history up to the last converged step kept."""
    from jaxform.simulation import SimulationError

    def boom(state):
        raise KeyError("a bug in the transfer")

    _corrupting_remesh(monkeypatch, boom)
    over = QUIET + ["mesh.nr=4", "mesh.nz=4", "die.reduction=0.15", "remesh.every_steps=5"]
    with pytest.raises(SimulationError, match=r"converged time 5 s \(stroke 0.375 mm\): "
                       r"KeyError: 'a bug in the transfer'"):  # fmt: skip
        try:
            jaxform.run(SEED, over)
        except SimulationError as err:
            assert len(err.result.history["time_s"]) == 6 and len(err.result.segments) == 1
            raise


def test_local_thickness_finds_the_flash_and_sizes_elements_across_it():
    """A flanged section with a flash 0.4 mm thick and 3 mm long beside a 2 x 3 mm body:
    along the flash (away from its ends) the thickness is 0.4 mm exactly; half-way up the
    body's axis it is the body's width; a square's vertices face nothing (their own sides
    and the legs of a corner never count).  With remesh.elements_across = 3 the new mesh
    has at least 3 elements over the flash's thickness (its thickness over the mean
    element size in the flash's middle: measured 3.6); without, fewer than 2 (1.8)."""
    from jaxform.section_mesh import densified, element_sizes, local_thickness

    poly = np.array([[0, 0], [5, 0], [5, 0.4], [2, 0.4], [2, 3], [0, 3]], float)
    labels = ["symmetry", "side", "top", "top", "top", "axis"]
    pts, labs, _ = densified(poly, labels, np.zeros(len(poly), bool), 0.25)
    t = local_thickness(pts)
    mid_flash = (pts[:, 0] > 2.6) & (pts[:, 0] < 4.4)
    assert np.allclose(t[mid_flash], 0.4, atol=1e-12)
    # on the axis half-way up the body: across to the wall at r = 2 (nearer to the axis'
    # ends the wall is less than twice as far along the boundary as straight: not across)
    body_axis = (pts[:, 0] == 0.0) & (pts[:, 1] > 1.2) & (pts[:, 1] < 1.8)
    assert body_axis.sum() == 3 and np.allclose(t[body_axis], 2.0, atol=1e-12)
    # a square's vertices face nothing across (only their own sides)
    assert np.all(np.isinf(local_thickness(np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float))))
    across_flash = []
    for across in (0, 3):
        settings = SimpleNamespace(element_size_mm=0.5, die_size_ratio=0.5,
                                   elements_across=across)  # fmt: skip
        p, lab = (pts, labs) if across else (poly, labels)
        mesh = polygon_quads(p, lab, element_sizes(p, np.zeros(len(p), bool), settings))
        centre = mesh.coords[mesh.elements].mean(axis=1)
        flash = (centre[:, 0] > 2.5) & (centre[:, 0] < 4.5)
        area = polygon_measure(mesh.coords[mesh.elements[flash]], False)
        across_flash.append(0.4 / np.sqrt(area.mean()))  # thickness / mean element size
    assert across_flash[1] >= 3.0 and across_flash[0] < 2.0, across_flash


def test_nodes_added_along_a_die_arc_are_moved_onto_it_with_the_volume_kept():
    """A section under a concave die arc (a circle of radius 2 mm about the origin, the
    material inside; its contact vertices every 10 deg) meshed at 0.1 mm: gmsh adds nodes
    on the chords, off the die by up to the sagitta (R (1 - cos 5 deg) = 7.6 um here).
    remesh.onto_dies moves each onto the circle (|x| = 2 to 1e-12); the free side gives
    back the volume the chords' slivers would add (0.34 %): the mesh's volume is the
    polygon's to 1e-12; the axis and mid-plane nodes do not move."""
    from jaxform.remesh import onto_dies

    arc = np.deg2rad(np.arange(40.0, 91.0, 10.0))
    top = np.column_stack([2.0 * np.cos(arc), 2.0 * np.sin(arc)])
    pts = np.vstack([[0.0, 0.0], [1.5, 0.0], [1.5, 0.8], [2.0 * np.cos(arc[0]), 1.2],
                     top[1:]])  # fmt: skip
    pts[3] = top[0]
    labels = ["symmetry", "side", "side"] + ["top"] * (len(top) - 1) + ["axis"]
    touching = np.r_[False, False, False, np.ones(len(top), bool)]
    touching[-1] = True  # (0, 2): the arc's end on the axis

    def gap_fn(p):
        r = np.linalg.norm(p, axis=1)  # 0 at the circle's centre, a node of the mesh
        return 2.0 - r, -p / np.maximum(r, 1e-12)[:, None]

    mesh = polygon_quads(pts, labels, np.full(len(pts), 0.1))
    new = onto_dies(mesh, (pts, touching), gap_fn, axisymmetric=True)
    top_nodes = np.asarray(mesh.node_sets["top"])
    r_old = np.linalg.norm(mesh.coords[top_nodes], axis=1)
    added = np.abs(r_old - 2.0) > 1e-9  # the nodes gmsh put on the chords
    assert added.sum() >= 5 and (2.0 - r_old[added]).max() > 5e-3
    np.testing.assert_allclose(np.linalg.norm(new.coords[top_nodes], axis=1), 2.0, atol=1e-12)
    volume = [polygon_measure(m.coords[m.elements], True).sum() for m in (mesh, new)]
    snapped = mesh.coords.copy()
    snapped[top_nodes] *= (2.0 / np.linalg.norm(mesh.coords[top_nodes], axis=1))[:, None]
    sliver = polygon_measure(snapped[mesh.elements], True).sum() - volume[0]
    assert sliver > 1e-4 * volume[0]  # what the move onto the arc alone would add
    assert abs(volume[1] - volume[0]) < 1e-12 * volume[0]
    for name in ("axis", "symmetry"):
        held = mesh.node_sets[name]
        assert np.array_equal(new.coords[held], mesh.coords[held])


def _two_dies(gaps_normals):
    """gap_fn of several dies: the least gap and its die's normal at each point."""

    def gap_fn(p):
        g, n = zip(*(f(p) for f in gaps_normals))
        k = np.argmin(np.stack(g), axis=0)
        return np.stack(g)[k, np.arange(len(p))], np.stack(n)[k, np.arange(len(p))]

    return gap_fn


def test_an_axis_from_one_die_to_another_is_no_chord():
    """The section of the arc test above standing on a flat bottom die (z = 0) too, so
    its axis runs from a contact vertex on the top die to one on the bottom die (as in
    a container, configs/backward_extrusion.toml).  The axis is held by its Dirichlet
    condition and is no chord of a die: its nodes stay where they are (exactly), and the
    nodes on the top arc's chords still go onto the arc (|x| = 2 to 1e-12).  Before, the
    axis nodes within a quarter of the axis' length of a die were moved onto it, the
    moved mesh folded, and onto_dies kept the unmoved mesh: every chord node stayed off
    its die (inside a convex one by up to 0.17 mm in the backward extrusion)."""
    from jaxform.remesh import onto_dies

    arc = np.deg2rad(np.arange(40.0, 91.0, 10.0))
    top = np.column_stack([2.0 * np.cos(arc), 2.0 * np.sin(arc)])
    pts = np.vstack([[0.0, 0.0], [1.5, 0.0], [1.5, 0.8], top])
    labels = ["symmetry", "side", "side"] + ["top"] * (len(top) - 1) + ["axis"]
    touching = np.r_[True, False, False, np.ones(len(top), bool)]  # (0, 0) on the bottom die

    def arc_die(p):
        r = np.linalg.norm(p, axis=1)
        return 2.0 - r, -p / np.maximum(r, 1e-300)[:, None]

    def bottom_die(p):
        return p[:, 1].copy(), np.tile([0.0, -1.0], (len(p), 1))

    mesh = polygon_quads(pts, labels, np.full(len(pts), 0.1))
    new = onto_dies(mesh, (pts, touching), _two_dies((arc_die, bottom_die)), axisymmetric=True)
    axis = np.asarray(mesh.node_sets["axis"])
    assert len(axis) > 10
    np.testing.assert_array_equal(new.coords[axis], mesh.coords[axis])
    top_nodes = np.asarray(mesh.node_sets["top"])
    assert np.abs(np.linalg.norm(mesh.coords[top_nodes], axis=1) - 2.0).max() > 5e-3
    np.testing.assert_allclose(np.linalg.norm(new.coords[top_nodes], axis=1), 2.0, atol=1e-12)


def test_nodes_a_chord_puts_inside_a_convex_die_corner_are_moved_out():
    """Material outside a convex die corner (a punch's nose: a disc of radius 1 mm about
    (0, 2)); the polygon's edge from 0.05 mm right of the disc's point at -40 deg (no
    contact vertex) to (0, 1) (on it) cuts through the disc, and gmsh's nodes on it lie
    inside the die (down to -0.08 mm).  onto_dies moves every node inside a die onto it (gap 0
    to 1e-12; the moved nodes keep their side of the die), and the free surface gives the
    volume back (the polygon's to 1e-12)."""
    from jaxform.remesh import onto_dies

    a = np.deg2rad(-40.0)
    pts = np.array([[0.0, 0.0], [3.0, 0.0], [3.0, 2.0 + np.sin(a)],
                    [np.cos(a) + 0.05, 2.0 + np.sin(a)], [0.0, 1.0]])  # fmt: skip
    labels = ["symmetry", "outer", "outer", "top", "axis"]
    touching = np.array([False, False, False, False, True])

    def nose(p):
        d = p - np.array([0.0, 2.0])
        r = np.linalg.norm(d, axis=1)
        return r - 1.0, d / r[:, None]

    mesh = polygon_quads(pts, labels, np.full(len(pts), 0.1))
    g_old, _ = nose(mesh.coords)
    assert g_old.min() < -0.07
    new = onto_dies(mesh, (pts, touching), nose, axisymmetric=True)
    g_new, _ = nose(new.coords)
    assert g_new.min() >= -1e-12
    inside = g_old < -1e-3
    np.testing.assert_allclose(g_new[inside], 0.0, atol=1e-12)
    volume = [polygon_measure(m.coords[m.elements], True).sum() for m in (mesh, new)]
    assert abs(volume[1] - volume[0]) < 1e-12 * volume[0]


def _nose(centre, radius):
    """gap_fn of a punch's nose: a disc (material outside it)."""

    def gap_fn(p):
        d = np.asarray(p) - np.asarray(centre)
        r = np.linalg.norm(d, axis=1)
        return r - radius, d / np.maximum(r, 1e-300)[:, None]

    return gap_fn


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4])
def test_a_polygon_a_convex_die_reaches_into_is_wrapped_round_it(seed):
    """Node contact holds nodes, not edges, off a die: a convex die arc the material flows
    round reaches across the edge between two contact nodes (the two-stage disk's finisher:
    0.13 mm into a 0.58 mm edge at its 0.3 mm flash-land entry; the new mesh then started
    with a node inside the die and its first step did not converge at the smallest step).
    Seeded cases: a disc die of random radius (0.2 - 2 mm) whose chord through the
    section's top (two contact vertices on the disc, a vertex between them inside it, depth
    10 - 90 % of the radius), axisymmetric or plane.  section_mesh.off_dies puts every
    vertex on or off the disc (gap >= -1e-12) and wraps the arc (every edge between two die
    vertices within 2 % of the die size of it at its midpoint, or too short to split:
    under twice 0.3 of the die size);
    volume_back gives the measure back (1e-12); neither moves the axis or mid-plane
    vertices; for a polygon the die does not reach into off_dies says so (None)."""
    from jaxform.section_mesh import DEEP, THIN, off_dies, volume_back

    rng = np.random.default_rng(seed)
    rho = rng.uniform(0.2, 2.0)
    depth = rng.uniform(0.1, 0.9) * rho
    axi = bool(rng.integers(2))
    top = 2.0 * rho + 1.0
    centre = (2.5 * rho, top + rho - depth)  # the disc reaches depth below the top
    half = np.sqrt(rho**2 - (rho - depth) ** 2)  # half the chord at z = top
    pts = np.array([[0.0, 0.0], [5.0 * rho, 0.0], [5.0 * rho, top], [centre[0] + half, top],
                    [centre[0], top], [centre[0] - half, top], [0.0, top]])  # fmt: skip
    labels = ["symmetry", "outer", "top", "top", "top", "top", "axis"]
    gap_fn = _nose(centre, rho)
    die_size = 0.25 * rho
    assert gap_fn(pts)[0].min() < -0.09 * rho
    new, new_labels = off_dies(pts, labels, gap_fn, die_size)
    new = volume_back(new, new_labels, gap_fn, polygon_measure(pts, axi), axi)
    g = gap_fn(new)[0]
    assert g.min() >= -1e-12
    on_die = g <= 1e-3
    assert on_die.sum() >= 5  # the arc is wrapped, not bridged
    a, b = new, np.roll(new, -1, axis=0)
    die_edges = on_die & np.roll(on_die, -1)
    mid_gap = gap_fn(0.5 * (a + b))[0]
    short = np.linalg.norm(b - a, axis=1) < 2 * THIN * die_size  # no room for a vertex
    assert np.all((mid_gap[die_edges] >= -max(1e-3, DEEP * die_size)) | short[die_edges])
    volume = [polygon_measure(p, axi) for p in (pts, new)]
    assert abs(volume[1] - volume[0]) < 1e-12 * volume[0]
    for held in ([0.0, 0.0], [5.0 * rho, 0.0], [0.0, top]):  # ends of the axis, mid-plane
        assert np.min(np.linalg.norm(new - held, axis=1)) == 0.0
    assert len(new_labels) == len(new)
    clear = _nose((centre[0], top + rho + 0.1), rho)  # the same disc 0.1 mm above the top
    assert off_dies(pts, labels, clear, die_size) is None


def _profile_die(profile):
    """gap_fn of a die above the polyline ``profile`` (r increasing; the material below
    it): the distance to the polyline, negative above it, and the unit normal from the
    die towards the material."""
    a, b = np.asarray(profile[:-1], float), np.asarray(profile[1:], float)

    def gap_fn(p):
        p = np.asarray(p, float)
        k, _, dist = nearest_on_segments(p, a, b)
        t = b[k] - a[k]
        z = np.interp(p[:, 0], np.asarray(profile)[:, 0], np.asarray(profile)[:, 1])
        sign = np.where(p[:, 1] <= z + 1e-12, 1.0, -1.0)
        normal = np.stack([t[:, 1], -t[:, 0]], axis=1) / np.linalg.norm(t, axis=1)[:, None]
        return sign * dist, normal

    return gap_fn


@pytest.mark.parametrize("axi", [True, False])
def test_a_volume_cut_at_the_flash_land_goes_back_to_the_flash(axi):
    """A remesh cuts what a convex die corner reached into off the section and gives the
    volume back to the free surface.  Late in a closed die the flash's tip face runs from
    the land to the mid-plane (no free vertex), and a pocket of the cavity (air under the
    rib's top corner) may be the only free surface: spread there, the flash's volume
    filled the cavity (the two-stage disk, one remesh: 1.7 % of the cavity in).  A half
    section with a 0.4 mm flash on a land from r = 6.4 mm, the rib's wall and top on the
    die and a pocket vertex 0.05 mm under the rib's top corner; 0.5 mm^3 (0.2 mm^2 plane)
    given back near the land's entry (section_mesh.volume_back with the cut's site): the
    measure is the target (1e-12), the flash tip's two vertices slide outward along the
    land and the mid-plane (z unchanged to 1e-12) by at least 80 % of the volume over the
    tip face's measure (most of it goes there), the pocket vertex moves under 1 % of
    the tip's move, and every vertex on the die stays on it (gap >= -1e-9)."""
    from jaxform.section_mesh import PUT_BACK_REACH, volume_back

    die = _profile_die([[0.0, 1.0], [4.3, 1.0], [4.6, 2.5], [6.1, 2.5], [6.4, 0.4],
                        [7.4, 0.4], [7.4, 1.5], [12.0, 1.5]])  # fmt: skip
    pts = np.array([[0.0, 0.0], [7.0, 0.0], [7.0, 0.4], [6.4, 0.4], [6.25, 1.45], [6.1, 2.5],
                    [5.0, 2.5], [4.66, 2.45], [4.45, 1.75], [4.3, 1.0], [2.0, 1.0],
                    [0.0, 1.0]])  # fmt: skip
    labels = ["symmetry", "side", "top", "top", "top", "top", "top", "top", "top", "top",
              "top", "axis"]  # fmt: skip
    g, _ = die(pts)
    pocket = 7
    assert 0.04 < g[pocket] < 0.06 and np.all(np.delete(g, [0, 1, pocket]) < 1e-12)
    added = 0.5 if axi else 0.2
    target = polygon_measure(pts, axi) + added
    site = np.array([[6.4, 0.4]])
    new = volume_back(pts.copy(), labels, die, target, axi, near=(site, PUT_BACK_REACH * 0.25))
    assert abs(polygon_measure(new, axi) - target) < 1e-12 * target
    tip = new[1:3] - pts[1:3]
    face = 2.0 * np.pi * 7.0 * 0.4 if axi else 0.4  # the tip face's measure per mm of move
    assert np.all(tip[:, 0] > 0.8 * added / face)
    np.testing.assert_allclose(new[1:3, 1], pts[1:3, 1], atol=1e-12)
    assert np.linalg.norm(new[pocket] - pts[pocket]) < 0.01 * tip[:, 0].min()
    on_die = np.delete(np.arange(len(pts)), [0, 1, pocket])
    assert die(new[on_die])[0].min() >= -1e-9


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_bunch_of_boundary_nodes_is_thinned_to_the_die_size(seed):
    """Material flowing into a die corner bunches its boundary nodes, and a remesh kept
    every one as a node: the two-stage disk's finisher at blocker friction 0.29 grew from
    479 to 2091 nodes over its last 3 um of stroke.  A section whose top carries seeded
    bunches (vertices 1 - 50 um apart): section_mesh.thinned keeps every vertex where the
    set changes and leaves no two consecutive kept vertices closer than the gap unless one
    of them is such a corner; a polygon with no bunch keeps every vertex."""
    from jaxform.section_mesh import thinned

    rng = np.random.default_rng(seed)
    bunches = [c + np.cumsum(rng.uniform(0.001, 0.05, rng.integers(5, 30)))
               for c in np.sort(rng.uniform(0.5, 4.0, 3))]  # fmt: skip
    xs = np.unique(np.concatenate([np.arange(0.0, 5.01, 0.25), *bunches]))[::-1]
    top = np.column_stack([xs[(xs > 0) & (xs < 5)], np.full(np.sum((xs > 0) & (xs < 5)), 2.0)])
    pts = np.vstack([[0.0, 0.0], [5.0, 0.0], [5.0, 2.0], top, [0.0, 2.0]])
    labels = ["symmetry", "side"] + ["top"] * (len(top) + 1) + ["axis"]
    gap = 0.075
    kept = thinned(pts, labels, gap)
    corner = np.array([labels[i - 1] != labels[i] for i in range(len(pts))])
    assert set(np.nonzero(corner)[0]) <= set(kept.tolist())
    d = np.linalg.norm(pts[np.roll(kept, -1)] - pts[kept], axis=1)
    ends_corner = corner[kept] | corner[np.roll(kept, -1)]
    assert np.all((d >= gap) | ends_corner)
    assert len(kept) < len(pts) - 20
    even = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.5, 1.0], [0.0, 1.0]])
    assert thinned(even, ["symmetry", "side", "top", "top", "axis"], gap).tolist() == [
        0,
        1,
        2,
        3,
        4,
    ]


def test_a_remesh_where_the_die_reaches_into_the_section_meshes_only_the_part_outside_it():
    """The flashless closed die (configs/closed_die.toml, 4 x 4, node contact only) at the
    time its die first reaches 0.3 of the remesh's die size into the undeformed billet
    (what node contact lets a convex arc do between two nodes): remesh() gives a mesh none
    of whose nodes lies deeper in the die than DEEP (0.1) of the die size (section_mesh:
    an edge that dips less stays; before, the old boundary was the new one, 0.3 deep),
    with the section's volume kept (1e-7: the overlap goes back to the free surface; the
    straight runs' vertices the free surface moved are no longer dropped exactly)."""
    from jaxform.remesh import remesh
    from jaxform.rezone import gap_function
    from jaxform.scenes import build_scene
    from jaxform.section_mesh import DEEP
    from jaxform.simulation import init

    over = QUIET + ["mesh.nr=4", "mesh.nz=4", "die.corner_contact=false",
                    "mesh.rezone_quality=0", "remesh.quality_below=0.3"]  # fmt: skip
    sc = build_scene(load_config("configs/closed_die.toml", over))
    coords = np.asarray(sc.inputs.coords)
    die_size = sc.remesh.element_size_mm * sc.remesh.die_size_ratio
    depth = 0.3 * die_size

    def deepest(t):
        return float(gap_function(sc.inputs.die, t)(coords)[0].min())

    lo, hi = 0.0, sc.t_end
    for _ in range(60):  # the time the die reaches that depth into the billet
        lo, hi = (
            (lo, 0.5 * (lo + hi)) if deepest(0.5 * (lo + hi)) < -depth else (0.5 * (lo + hi), hi)
        )
    state = init(sc)[0]
    state = replace(state, t=jnp.asarray(hi, dtype=state.t.dtype))
    assert deepest(hi) < -0.99 * depth
    done = remesh(sc, state, sc.remesh)
    gap = gap_function(sc.inputs.die, hi)(np.asarray(done.scene.inputs.coords))[0]
    assert gap.min() >= -DEEP * die_size
    assert abs(done.report.volume_change) < 1e-7


def test_a_section_gmsh_cannot_quad_mesh_is_tried_again_finer(monkeypatch):
    """Generated closed die 11 stopped at 99.8 % of its stroke: 'remeshing failed: gmsh
    gave no all-quad mesh' (triangles left by every algorithm at the wanted sizes).  The
    new mesh is tried again at 0.8 and 0.65 of the sizes, last split into quadrilaterals;
    here gmsh is made to fail at the first sizes: the second try's mesh comes back (its
    sizes 0.8 of the wanted, and it says so), and when every try fails the error names
    each try."""
    import jaxform.section_mesh as sm
    from jaxform.mesh import MeshError

    pts, labels = _barrel()
    tried = []
    real = sm.polygon_quads

    def flaky(points, labs, sizes, split=False):
        tried.append((float(np.max(sizes)), split))
        if len(tried) == 1:
            raise MeshError("gmsh left non-quadrilateral elements (types [2, 3])")
        return real(points, labs, sizes, split)

    monkeypatch.setattr(sm, "polygon_quads", flaky)
    mesh, how = sm.quads_of(pts, labels, np.full(len(pts), 0.3))
    assert tried == [(0.3, False), (pytest.approx(0.24), False)]
    assert mesh.elements.shape[1] == 4 and how.size_factor == 0.8 and str(how) == "sizes x 0.8"

    def never(points, labs, sizes, split=False):
        raise MeshError("no quads")

    monkeypatch.setattr(sm, "polygon_quads", never)
    with pytest.raises(MeshError, match=r"x 1: no quads; x 0.8: no quads; x 0.65: no quads; "
                                         r"split: no quads"):  # fmt: skip
        sm.quads_of(pts, labels, np.full(len(pts), 0.3))


def _saved_polygon(name):
    """(points, labels, sizes) of a remesh's polygon saved in tests/data (r, z, the label
    of the edge to the next point, the wanted element size; mm)."""
    data = np.genfromtxt(Path(__file__).parent / "data" / name, delimiter=",", names=True,
                         dtype=None, encoding="utf-8")  # fmt: skip
    return (np.column_stack([data["r_mm"], data["z_mm"]]), [str(x) for x in data["label"]],
            np.asarray(data["size_mm"], dtype=float))  # fmt: skip


def test_the_finisher_fin_that_gmsh_cannot_quad_mesh_is_split_into_quads():
    """The two-stage disk design's finisher (experiments/two_stage_disk_design.toml)
    stopped at 1.89 of its 2 mm stroke: 'gmsh gave no all-quad mesh' at every size.  Its
    section (tests/data/finisher_fin_polygon.csv: the remesh's polygon and wanted sizes,
    saved from that run) has a fin of material along the rib cavity's top, a closing
    pocket's edge: a tip of 21 deg between the die face and the free surface, under 50 um
    thick for 0.15 mm.  Blossom leaves a triangle in it at the wanted sizes and at 0.8 and
    0.65 of them (each algorithm: checked, so the fixture still reproduces the failure).
    Split into quadrilaterals it meshes.  References: the polygon itself (every vertex a
    node, the area to 1e-12 relative, each set's facets on that set's edges), corner
    quality > 0 (the fin's tip corner is sin 21 deg = 0.36 at best; measured 0.141)."""
    import jaxform.section_mesh as sm
    from jaxform.mesh import MeshError

    pts, labels, sizes = _saved_polygon("finisher_fin_polygon.csv")
    for factor in sm.SIZE_RETRIES:
        with pytest.raises(MeshError, match="non-quadrilateral"):
            polygon_quads(pts, labels, factor * sizes)
    mesh, how = sm.quads_of(pts, labels, sizes)
    assert how.split and str(how).startswith("split") and mesh.elements.shape[1] == 4
    assert 0.1 < min_quality(mesh.coords, mesh.elements) < np.sin(np.deg2rad(21.5))
    area = polygon_measure(mesh.coords[mesh.elements], False).sum()
    assert abs(area - polygon_measure(pts[None], False)[0]) < 1e-12 * area
    assert np.linalg.norm(mesh.coords[:, None] - pts[None], axis=2).min(axis=0).max() < 1e-12
    edge_of = {}  # each boundary facet must lie on a polygon edge of its own set
    a, b = pts, np.roll(pts, -1, axis=0)
    for name, facets in mesh.facet_sets.items():
        mid = mesh.coords[facets].mean(axis=1)
        d = b - a
        s = np.clip(np.einsum("pmi,mi->pm", mid[:, None] - a, d) / (d**2).sum(1), 0, 1)
        dist = np.linalg.norm(mid[:, None] - (a + s[..., None] * d), axis=2)
        edge_of[name] = {labels[k] for k in np.argmin(dist, axis=1)}
        assert dist.min(axis=1).max() < 1e-9
    assert edge_of == {name: {name} for name in set(labels)}


def test_a_boundary_that_crosses_itself_is_untangled():
    """A loop the boundary makes by crossing itself is cut off at the crossing (gmsh, given
    a self-crossing polygon, never returns).  Reference, by hand: the rectangle 4 x 2 whose
    top edge (4, 2) -> (1, 2) runs on to (2, 3) and comes back down through it at (2, 2)
    to (2, 1.5), then to the axis: the loop (2, 2), (1, 2), (2, 3) is clockwise (area
    0.5, counted negative), the rest has area 7; the untangled polygon is the rest, x =
    (2, 2) between the edges it joins, each edge's label kept, no crossing left."""
    from jaxform.section_mesh import first_crossing, untangled

    pts = np.array([[0, 0], [4, 0], [4, 2], [1, 2], [2, 3], [2, 1.5], [0, 1.5]], float)
    labels = ["symmetry", "side", "top", "t3", "t4", "t5", "axis"]
    assert first_crossing(pts)[:2] == (2, 4)
    out, labs, cut = untangled(pts, labels)
    np.testing.assert_allclose(out, [[0, 0], [4, 0], [4, 2], [2, 2], [2, 1.5], [0, 1.5]],
                               atol=1e-15)  # fmt: skip
    assert labs == ["symmetry", "side", "top", "t4", "t5", "axis"]
    assert cut == pytest.approx(0.5, abs=1e-14)
    assert polygon_measure(out[None], False)[0] == pytest.approx(7.0, abs=1e-14)
    assert first_crossing(out) is None and first_crossing(out[[0, 1, 2, 5]]) is None
    assert untangled(out, labs)[2] == 0.0  # a simple polygon stays as it is


def test_a_fold_whose_sides_have_closed_is_cut_like_a_crossing():
    """A slit (a fold whose two sides have closed on each other without crossing) is cut
    at the midpoint of its mouth: kept, it gave the new mesh poor elements from the start
    and, pressed further, a section overlapping itself (generated die 29). Reference, by
    hand: the rectangle 4 x 2 with a slit from its top edge down to (2, 1), its mouth
    (2 -+ w/2, 2): with w = 1e-4 mm (< TOUCH_GAP_MM) the polygon is the rectangle again,
    the mouth's vertices merged at (2, 2), the cut the slit's area w / 2 (1e-15); with w
    = 1e-2 mm (an open fold) and without ``touch`` it stays as it is."""
    from jaxform.contact import TOUCH_GAP_MM
    from jaxform.section_mesh import first_touch, fold_cut, untangled

    def slit(w):
        return np.array([[0, 0], [4, 0], [4, 2], [2 + w / 2, 2], [2, 1], [2 - w / 2, 2],
                         [0, 2]], float)  # fmt: skip

    labels = ["symmetry", "side", "top", "fold", "fold", "top", "axis"]
    out, labs, cut = untangled(slit(1e-4), labels, touch=TOUCH_GAP_MM)
    np.testing.assert_allclose(out, [[0, 0], [4, 0], [4, 2], [2, 2], [0, 2]], atol=1e-15)
    assert labs == ["symmetry", "side", "top", "top", "axis"]
    assert cut == pytest.approx(0.5e-4, abs=1e-15)
    assert polygon_measure(out[None], False)[0] == pytest.approx(8.0, abs=1e-14)
    assert first_touch(slit(1e-4), TOUCH_GAP_MM) == (3, 5)
    assert fold_cut(slit(1e-4), labels, 0.01)[2] == cut
    for pts, touch in ((slit(1e-2), TOUCH_GAP_MM), (slit(1e-4), 0.0)):
        out, labs, cut = untangled(pts, labels, touch=touch)
        assert np.array_equal(out, pts) and labs == labels and cut == 0.0


def test_the_finisher_fold_that_hung_gmsh_is_untangled_and_meshes():
    """The two-stage disk design's finisher hung at 1.95 mm of its stroke inside gmsh's
    mesh.generate (the run waited 10 min): the fin at the rib cavity's top corner (the
    test above) had been pressed over, and the remesh's polygon (tests/data/
    finisher_fold_polygon.csv, saved from that run; not given to gmsh here, it would
    hang) crosses itself: edge 4 -> 5 crosses edge 7 -> 8.  Untangled, the fin's tip
    beyond the crossing (0.00175 mm^2, the shoelace area of the cut loop) is cut and the
    rest meshes at the wanted sizes on the first try.  References: the areas by the
    shoelace formula (1e-12), the kept vertices the polygon's own."""
    import jaxform.section_mesh as sm

    pts, labels, sizes = _saved_polygon("finisher_fold_polygon.csv")
    i, j, x = sm.first_crossing(pts)
    assert (i, j) == (4, 7)
    out, labs, cut = sm.untangled(pts, labels)
    lobe = np.vstack([x, pts[5:8]])
    assert cut == pytest.approx(polygon_measure(lobe[None], False)[0], rel=1e-12)
    assert 1.7e-3 < cut < 1.8e-3
    assert np.array_equal(out, np.vstack([pts[:5], x, pts[8:]]))
    whole = polygon_measure(pts[None], False)[0]  # the lobe is counter-clockwise too
    assert polygon_measure(out[None], False)[0] == pytest.approx(whole - cut, rel=1e-12)
    kept_sizes = np.concatenate([sizes[:5], [sizes[4:8].min()], sizes[8:]])
    mesh, how = sm.quads_of(out, labs, kept_sizes)
    assert not how and str(how) == "" and mesh.elements.shape[1] == 4
    assert min_quality(mesh.coords, mesh.elements) > 0.0


def test_a_fold_cut_a_hair_from_a_vertex_leaves_no_needle():
    """Generated die 29 (seeded flanged hub) stopped at 4.068 mm: its remesh's polygon
    (tests/data/generated_die29_fold_polygon.csv, saved from the run at 4.06 mm) crosses
    itself where a fin folded over, and the crossing falls 5.5 um from the fold's next
    vertex.  Cut there alone, it leaves a needle (two vertices 5.5 um apart, turns of 145
    and 157 deg) that gmsh meshes only split, with corners of quality ~0.02 (the step
    after it failed).  :func:`fold_cut` drops the vertices nearer than THIN x the die
    size to the one before: no two vertices closer than that, the polygon meshes on the
    first try with every corner above 0.3 (measured 0.62), the cut area unchanged."""
    import jaxform.section_mesh as sm

    pts, labels, sizes = _saved_polygon("generated_die29_fold_polygon.csv")
    min_gap = 0.0578328695  # THIN x the run's die size (0.5 x 0.3856 mm)

    def sizes_at(points):  # each vertex takes the wanted size of the nearest saved one
        return sizes[np.argmin(np.linalg.norm(points[:, None] - pts[None], axis=2), axis=1)]

    bare, bare_labels, cut = sm.untangled(pts, labels)
    edges = np.linalg.norm(np.roll(bare, -1, axis=0) - bare, axis=1)
    assert cut > 0.0 and edges.min() < 1e-2  # the needle
    mesh, how = sm.quads_of(bare, bare_labels, sizes_at(bare))
    assert how.split and min_quality(mesh.coords, mesh.elements) < 0.05
    out, labs, cut2 = sm.fold_cut(pts, labels, min_gap)
    assert cut2 == cut
    assert np.linalg.norm(np.roll(out, -1, axis=0) - out, axis=1).min() >= min_gap
    mesh, how = sm.quads_of(out, labs, sizes_at(out))
    assert not how and min_quality(mesh.coords, mesh.elements) > 0.3


def test_the_run_notes_what_the_mesher_needed():
    """The run's note counts the remeshes whose mesher needed finer sizes, the split into
    quadrilaterals or a fold cut (RemeshReport.mesher as quads_of and new_section_mesh
    write it), and names the first; no note where every first try worked."""
    from jaxform.remesh import RemeshReport, mesher_note
    from jaxform.section_mesh import MesherHelp

    def report(t, mesher):
        return RemeshReport(t, 1, 1, 1, 1, 0.5, 0.5, 0.0, 0.0, 0.0, 0.0, "quality", mesher)

    hows = [MesherHelp(), MesherHelp(0.8), MesherHelp(split=True),
            MesherHelp(fold_cut_mm2=0.00175), MesherHelp()]  # fmt: skip
    note = mesher_note([report(0.1 * k, h) for k, h in enumerate(hows)])
    assert note.startswith("note: 3 of 5 remeshes needed more than the mesher's first try "
                           "(1 finer sizes, 1 split into quads, 1 a fold cut; first at "
                           "t = 0.1 s: sizes x 0.8)"), note  # fmt: skip
    assert mesher_note([report(0.0, MesherHelp())]) == "" and mesher_note([]) == ""
    both = MesherHelp(0.65, fold_cut_mm2=0.002)
    assert str(both) == "a fold crossed the boundary: 0.002 mm^2 cut; sizes x 0.65"
    assert both.kinds() == ("finer sizes", "a fold cut")
    assert str(hows[2]) == "split (gmsh left triangles at sizes x 1, 0.8, 0.65)"


def test_no_new_mesh_for_the_last_step_alone():
    """A trigger for the steps ahead (here every 7 steps of a 15-step run) that fires on
    the step before the last adapts nothing: the new mesh would serve the last step alone
    and its row would read the remesh's transient. Step 7 (eight steps left) remeshes,
    step 14 does not; with every 14 steps the run equals the unremeshed one."""
    over = QUIET + ["mesh.nr=4", "mesh.nz=4", "die.reduction=0.15"]
    plain = jaxform.run(SEED, over).history
    assert len(plain["force_N"]) == 16  # 15 steps of 1 s
    res = jaxform.run(SEED, over + ["remesh.every_steps=7"])
    assert list(np.nonzero(res.history["remeshed"])[0]) == [7]
    assert len(res.remeshes) == 1 and len(res.history["force_N"]) == 16
    late = jaxform.run(SEED, over + ["remesh.every_steps=14"])
    assert not np.any(late.history["remeshed"]) and not late.remeshes
    np.testing.assert_allclose(late.history["force_N"], plain["force_N"], rtol=1e-12)


def test_a_last_step_that_breaks_the_kept_mesh_is_taken_again_on_a_new_one(monkeypatch):
    """The quality trigger fires on the step before the last with the mesh still above
    HOLDS of the threshold, so the run keeps its mesh for the last step (the test above);
    where that step leaves the mesh below HOLDS of the threshold, the run adapts after all
    and takes the last step again on the new mesh (generated die 29: quality 0.268 ->
    0.0017 in its last step, -6.5 % of force).  Set up on the unremeshed run's own
    qualities q_k (falling step by step): the threshold between q_13 and q_14, HOLDS
    between q_15 and q_14 over it: the row of step 14 remeshes and the run still has 15
    steps; with HOLDS 0.5 (the last step keeps the mesh above it) nothing is remeshed and
    the run equals the unremeshed one.  (A 4 x 6 mesh: its elements start square, so the
    quality falls from 1 at every step.)"""
    import jaxform.triggers as triggers

    # full Newton with and without [remesh] ('auto' keeps a factorization only without)
    over = QUIET + ["mesh.nr=4", "mesh.nz=6", "die.reduction=0.15", "solver.newton=newton"]
    plain = jaxform.run(SEED, over).history
    q = plain["mesh_quality"]
    assert q[13] > q[14] > q[15]
    threshold = float(0.5 * (q[13] + q[14]))
    kept = jaxform.run(SEED, over + [f"remesh.quality_below={threshold!r}"])
    assert not np.any(kept.history["remeshed"])
    np.testing.assert_allclose(kept.history["force_N"], plain["force_N"], rtol=1e-12)
    monkeypatch.setattr(triggers, "HOLDS", 0.5 * (q[14] + q[15]) / threshold)
    res = jaxform.run(SEED, over + [f"remesh.quality_below={threshold!r}"])
    assert list(np.nonzero(res.history["remeshed"])[0]) == [14]
    assert len(res.remeshes) == 1 and len(res.history["force_N"]) == 16
    # frictionless upsetting is homogeneous: the new mesh's last step carries the same force
    assert res.history["force_N"][-1] == pytest.approx(plain["force_N"][-1], rel=1e-8)


def test_a_mesh_that_is_not_one_sheet_is_refused_and_gmsh_tries_the_next_algorithm(monkeypatch):
    """Reference: the definition of a sheet of counter-clockwise quads (each edge walked
    once each way at most, the boundary one loop).  A gmsh mesh of the shipped two-stage
    disk's finisher folded one quad over its neighbours near the flash land (an edge
    walked twice the same way, the boundary touching itself at a node) and the run then
    ended in a traceback; such a mesh now counts as that algorithm's failure."""
    import jaxform.mesh as mesh_mod
    from jaxform.mesh import MeshError, check_sheet, mapped_quad

    good = mapped_quad(np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]]), 4, 2)
    check_sheet(good.elements)
    overlapping = np.vstack([good.elements, good.elements[:1]])
    sq = np.array([[0, 1, 2, 3]])
    pinched = np.vstack([sq, np.array([[2, 4, 5, 6]])])  # two squares sharing node 2
    apart = np.vstack([sq, sq + 4])
    for bad, why in ((overlapping, "overlapping"), (pinched, "touches itself"),
                     (apart, "not one closed loop")):  # fmt: skip
        with pytest.raises(MeshError, match=why):
            check_sheet(bad)

    pts = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]])
    labels = ["bottom", "outer", "top", "axis"]
    real = mesh_mod._gmsh_quads
    tried = []

    def first_folds(p, lab, sizes, segments, how):
        tried.append(how[0])
        m = real(p, lab, sizes, segments, how)
        if how[0] == mesh_mod.QUAD_ALGORITHMS[0]:
            m = replace(m, elements=np.vstack([m.elements, m.elements[:1]]))
        return m

    monkeypatch.setattr(mesh_mod, "_gmsh_quads", first_folds)
    mesh = polygon_quads(pts, labels, np.full(4, 0.25))
    check_sheet(mesh.elements)
    assert tried[:2] == list(mesh_mod.QUAD_ALGORITHMS[:2])

    def always_folds(p, lab, sizes, segments, how):
        m = real(p, lab, sizes, segments, how)
        return replace(m, elements=np.vstack([m.elements, m.elements[:1]]))

    monkeypatch.setattr(mesh_mod, "_gmsh_quads", always_folds)
    with pytest.raises(MeshError, match="overlapping"):
        polygon_quads(pts, labels, np.full(4, 0.25))
