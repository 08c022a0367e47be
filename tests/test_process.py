"""Multi-stage processes ([[process.operation]], jaxform.process): each test names its
reference and tolerance.  The scenes are the seed billet on a 3 x 3 mesh, a few steps
each; the forming operations share one compiled program (same model and die shapes)."""

import tomllib
from dataclasses import replace
from functools import cache

import numpy as np
import pytest
from cli_harness import assert_refused

import jaxform
import jaxform.io
from jaxform.config import load_config, typed
from jaxform.driver import run
from jaxform.errors import ConfigError
from jaxform.mesh import boundary_edges
from jaxform.postprocess import nodal_temperature, positions
from jaxform.process import trimmed_polygon
from jaxform.scenes import build_scene
from jaxform.simulation import init, simulate

SEED = "configs/upsetting_seed.toml"
SMALL = ["mesh.nr=3", "mesh.nz=3", "time.dt_s=2.5", "output.fields=false", "output.plots=false"]
# the seed's history on this mesh at die.reduction = 0.1 before processes existed (commit
# 8fca7bd, main with presses and hammers): force_N and time_s of its 5 rows
SEED_FORCE_N = [0.0, 279.82002407882163, 303.281930224053, 323.0772470839838, 340.82298169774083]
# a cone die 0.005 mm above the axis of the part the first blow leaves (top at 3.375 mm)
CONE = [[0.0, 3.38], [6.0, 3.68]]
TRIM_RADIUS = 2.6


def seed_document(operations=None) -> dict:
    with open(SEED, "rb") as f:
        doc = tomllib.load(f)
    doc["mesh"].update(nr=3, nz=3)
    doc["time"]["dt_s"] = 2.5
    doc["die"]["reduction"] = 0.1
    doc["output"] = {"fields": False, "plots": False}
    if operations is not None:
        doc["process"] = {"operation": operations}
    return doc


FIRST = {"kind": "forming", "name": "first", "die": {"reduction": 0.1}}
SECOND = {"kind": "forming", "name": "second", "travel_mm": 0.3,
          "die": {"profile_mm": CONE, "speed_mm_s": 0.15}}  # fmt: skip


@cache
def single():
    """The first blow alone: the seed config without a process."""
    return run(seed_document())


@cache
def process():
    """First blow, the cone die's blow, a trim."""
    trim = {"kind": "trim", "name": "cut", "radius_mm": TRIM_RADIUS}
    return run(seed_document([FIRST, SECOND, trim]))


def test_one_operation_process_and_seed_history_unchanged():
    """A single-operation config gives the history it gave before processes existed
    (the times of commit 8fca7bd's run to 1e-12, its forces to 1e-10 relative: the same
    roots to the solver's rtol, the step from rest now solved from a probe's predictor,
    2.2e-11 apart), and a process of that one forming operation gives the same history
    (1e-12)."""
    h = single().history
    np.testing.assert_allclose(h["time_s"], [0.0, 2.5, 5.0, 7.5, 10.0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(h["force_N"], SEED_FORCE_N, rtol=1e-10, atol=1e-12)
    one = run(seed_document([FIRST])).history
    for k in ("time_s", "stroke_mm", "force_N", "friction_work_Nmm"):
        np.testing.assert_allclose(one[k], h[k], rtol=1e-12, atol=1e-12, err_msg=k)
    assert np.all(one["operation"] == 1)


def test_two_forming_operations_equal_the_single_operations():
    """Operation 1 of the process equals the first blow run alone (every row, 1e-12);
    operation 2 equals a run of the cone die built by hand on the first blow's deformed
    mesh and started from its end state (u = 0, F = I, stress, s, eqps and the nodal
    pressure kept; contact afresh), 1e-12 relative; the process clock goes on from the
    first blow's end."""
    res, first = process(), single()
    h = res.history
    op1 = h["operation"] == 1
    for k in ("time_s", "stroke_mm", "force_N"):
        np.testing.assert_allclose(h[k][op1], first.history[k], rtol=1e-12, atol=1e-12)
    # the cone die's blow, by hand
    sc1, st1 = first.final_scene, first.final_state
    pos = positions(sc1, np.asarray(st1.x))
    mesh2 = replace(sc1.mesh, coords=pos)
    top = float(pos[:, 1].max())
    doc = seed_document()
    doc["die"].update(profile_mm=CONE, speed_mm_s=0.15, reduction=0.3 / top)
    scene2 = build_scene(typed(load_config(doc)), mesh2)
    lay1, lay2 = sc1.model.layout, scene2.model.layout
    x = np.zeros(lay2.n_dofs)
    lay2.nodal(x)[:, 2:] = lay1.nodal(np.asarray(st1.x))[:, 2:]
    start, _ = init(scene2)
    eye = np.broadcast_to(np.eye(3), np.asarray(st1.gauss.F).shape)
    start = replace(start, x=x, gauss=replace(st1.gauss, F=eye),
                    friction_work=st1.friction_work, heat_mJ=st1.heat_mJ)  # fmt: skip
    ref = simulate(scene2, start=start).history
    op2 = h["operation"] == 2
    np.testing.assert_allclose(h["force_N"][op2], ref["force_N"][1:], rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(h["stroke_mm"][op2], ref["stroke_mm"][1:], rtol=1e-12)
    np.testing.assert_allclose(h["time_s"][op2], 10.0 + ref["time_s"][1:], rtol=1e-12)
    assert abs(h["stroke_mm"][op2][-1] - 0.6) < 1e-12  # travel_mm = 0.3, half height
    assert h["force_N"][op2][-1] > h["force_N"][op1][-1]  # the part hardened and grew


def _pappus(poly: np.ndarray) -> float:
    """Volume of revolution about r = 0 of a counter-clockwise polygon (mm^3)."""
    x, y = poly[:, 0], poly[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    return float(2.0 * np.pi * np.sum((x * yn - xn * y) * (x + xn)) / 6.0)


def _beyond(quad: np.ndarray, radius: float) -> np.ndarray:
    """The part of a convex quad at r >= radius (Sutherland-Hodgman, one edge)."""
    out = []
    for p, q in zip(quad, np.roll(quad, -1, axis=0)):
        if p[0] >= radius:
            out.append(p)
        if (p[0] >= radius) != (q[0] >= radius):
            s = (radius - p[0]) / (q[0] - p[0])
            out.append(p + s * (q - p))
    return np.asarray(out).reshape(-1, 2)


def test_trim_removes_the_volume_beyond_the_radius():
    """The trim removes the volume of revolution of the section beyond r = 2.6 mm, twice
    (the half-height model's two halves): the reference clips each deformed element at
    the radius and sums the pieces' Pappus volumes (relative 1e-12); the kept mesh holds
    the rest (1e-12) and nothing beyond the radius; the state came along (eqps within the
    old range, the clock held, the dies where the blow left them, no force)."""
    res = process()
    before = res.runs[1].result
    pos = positions(before.final_scene, np.asarray(before.final_state.x))
    quads = pos[np.asarray(before.final_scene.mesh.elements)]
    ref = sum(_pappus(p) for q in quads if len(p := _beyond(q, TRIM_RADIUS)) >= 3)
    trim = res.runs[2]
    assert ref > 0.1
    assert abs(trim.trimmed_volume - 2.0 * ref) <= 2e-12 * ref  # both halves of the part
    total = sum(_pappus(q) for q in quads)
    kept = trim.result.final_scene
    kept_pos = np.asarray(kept.inputs.coords)
    kept_volume = sum(_pappus(q) for q in kept_pos[np.asarray(kept.mesh.elements)])
    assert abs(kept_volume + ref - total) <= 1e-12 * total
    assert kept_pos[:, 0].max() <= TRIM_RADIUS + 1e-12
    eqps_old = np.asarray(before.final_state.gauss.mat.eqps)
    eqps_new = np.asarray(trim.result.final_state.gauss.mat.eqps)
    assert eqps_old.min() - 1e-12 <= eqps_new.min() and eqps_new.max() <= eqps_old.max() + 1e-12
    h = res.history
    assert h["operation"][-1] == 3 and h["time_s"][-1] == h["time_s"][-2]
    assert h["stroke_mm"][-1] == h["stroke_mm"][-2] and h["force_N"][-1] == 0.0


def test_trimmed_polygon_of_a_notched_section():
    """A section with a step (a flash under a taller part) cut at r = 2: the kept polygon
    is the rectangle [0, 2] x [0, 3] (shoelace area 6, exact), its cut edge labelled
    side; a cut through the axis leaves nothing."""
    pts = np.array([[0, 0], [4, 0], [4, 1], [3, 1], [3, 3], [0, 3]], float)
    labels = ["symmetry", "side", "top", "side", "top", "axis"]
    kept, kept_labels = trimmed_polygon(pts, labels, 2.0)
    x, y = kept[:, 0], kept[:, 1]
    assert 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) == 6.0
    assert kept_labels.count("side") == 1 and kept[:, 0].max() == 2.0
    with pytest.raises(ValueError):
        trimmed_polygon(pts + [1.0, 0.0], labels, 0.5)


def _lumped_reference(pos, mesh, tau_inputs, dts):
    """Backward-Euler lumped cooling factor prod 1 / (1 + dt / tau), tau = rho c V / (h A):
    V and A (the exposed top and side, Pappus) of the part at the dwell's start."""
    rho_c, h = tau_inputs
    faces = np.concatenate([mesh.facet_sets[s] for s in ("top", "side")])
    a, b = pos[faces[:, 0]], pos[faces[:, 1]]
    area = float(np.sum(np.linalg.norm(b - a, axis=1) * np.pi * (a[:, 0] + b[:, 0])))
    edges = boundary_edges(np.asarray(mesh.elements))
    volume = float(-_pappus_edges(pos, edges))
    tau = rho_c * volume / (h * area)  # s: mJ/(mm^3 K) mm^3 / (mW/(mm^2 K) mm^2)
    return float(np.prod(1.0 / (1.0 + np.asarray(dts) / tau))), tau


def _pappus_edges(pos, edges):
    a, b = pos[edges[:, 0]], pos[edges[:, 1]]
    return -np.sum((a[:, 0] * b[:, 1] - b[:, 0] * a[:, 1]) * (a[:, 0] + b[:, 0])) * np.pi / 3.0


@cache
def hot():
    """A small blow, 1 s in air, 0.5 s in a furnace at 800 K, set to 700 K (coupled heat,
    convection h = 2000 W/m^2 K, no radiation)."""
    doc = seed_document([
        {"kind": "forming", "name": "blow", "die": {"reduction": 0.01}},
        {"kind": "dwell", "name": "air", "time_s": 1.0, "dt_s": 0.05, "htc_air_W_m2K": 2000.0,
         "emissivity": 0.0},
        {"kind": "reheat", "name": "furnace", "furnace_temperature_K": 800.0, "time_s": 0.5,
         "dt_s": 0.05, "htc_W_m2K": 2000.0, "emissivity": 0.0},
        {"kind": "reheat", "name": "set", "set_temperature_K": 700.0},
    ])  # fmt: skip
    doc["thermal"] = {"model": "coupled", "die_temperature_K": 673.0}
    return run(doc)


def _lumped_check(result, t_ambient, tolerance):
    """(start, end mean temperature, BE lumped end, exponential end, tau) of a run in air
    or a furnace at t_ambient (h = 2000 W/m^2 K)."""
    th = result.scene.inputs.thermal
    t1 = float(result.history["mean_temperature_K"][0])
    rho_c = float(th.density_kg_m3 * th.specific_heat_J_kgK) * 1e-6  # mJ/(mm^3 K)
    pos = np.asarray(result.scene.inputs.coords)
    factor, tau = _lumped_reference(pos, result.scene.mesh, (rho_c, 2000.0e-3),
                                    result.history["dt_s"][1:])  # fmt: skip
    t_end = float(result.history["mean_temperature_K"][-1])
    duration = float(result.history["time_s"][-1])
    assert abs(t_end - (t_ambient + (t1 - t_ambient) * factor)) <= tolerance * abs(t1 - t_ambient)
    exact = t_ambient + (t1 - t_ambient) * np.exp(-duration / tau)
    assert abs(t_end - exact) <= 0.03 * abs(t1 - t_ambient)
    return t1, t_end


def test_dwell_cools_as_the_lumped_solution():
    """A dwell in air (convection h = 2000 W/m^2 K, no radiation) after a small blow:
    Biot h (V/A) / k ~ 0.01, so the mean temperature follows the lumped capacitance
    solution T_air + (T_1 - T_air) prod 1/(1 + dt/tau) of the same backward-Euler steps,
    tau = rho c V / (h A), within 1 % of T_1 - T_air (the internal gradient, ~Bi/2), and
    the exponential exp(-t/tau) within 3 %; the temperatures spread less than
    Bi (T_end - T_air) with Bi = h (R + H/2) / k."""
    res = hot()
    blow, dwell = res.runs[0].result, res.runs[1].result
    th = dwell.scene.inputs.thermal
    t_air = float(th.air_temperature_K)
    t1, t_end = _lumped_check(dwell, t_air, 0.01)
    assert abs(t1 - float(blow.history["mean_temperature_K"][-1])) < 1e-9  # carried
    assert t_end < t1 - 0.2 * (t1 - t_air)  # it did cool
    pos = np.asarray(dwell.scene.inputs.coords)
    temp = nodal_temperature(dwell.final_scene, np.asarray(dwell.final_state.x))
    # nearly uniform: the spread is of the order Bi (T - T_air), Bi = h (R + H/2) / k
    biot = 2000.0e-3 * (pos[:, 0].max() + pos[:, 1].max()) / float(th.conductivity_W_mK)
    assert np.ptp(temp) < biot * (t_end - t_air)
    assert np.count_nonzero(res.history["operation"] == 2) == len(dwell.history["time_s"]) - 1


def test_reheat_in_a_furnace_and_to_a_set_temperature():
    """The furnace (800 K, h = 2000 W/m^2 K, 0.5 s) heats the part as the lumped solution
    of its steps (1 % of the difference to the furnace) and the exponential (3 %); a set
    temperature puts every node at 700 K (1e-9 K) in one row at the same time."""
    res = hot()
    furnace = res.runs[2].result
    t2, t3 = _lumped_check(furnace, 800.0, 0.01)
    assert abs(t2 - float(res.runs[1].result.history["mean_temperature_K"][-1])) < 1e-9
    assert t3 > t2 + 0.2 * (800.0 - t2)
    h = res.history
    assert h["operation"][-1] == 4 and h["time_s"][-1] == h["time_s"][-2]
    for k in ("mean", "min", "max"):
        assert abs(h[f"{k}_temperature_K"][-1] - 700.0) < 1e-9


def _blocker_then_air() -> dict:
    """A flat blocker (0.5 mm of travel at 10 mm/s, die at 473 K, shear friction 0.3) on
    an 8 x 5 q1p0 billet of 1.01 x the volume of a 10 x 6 mm one (Al 1100, 673 K), then
    one 0.25 s step in air: a two-stage disk's start that failed in its dwell."""
    f = 1.01 ** (1.0 / 3.0)
    flat = [[0.0, 3.3], [12.0, 3.3]]
    blocker = {"kind": "forming", "name": "blocker", "travel_mm": 0.5,
               "die": {"corner_radius_mm": 0.5, "profile_mm": flat}}  # fmt: skip
    return {
        "billet": {"diameter_mm": 10.0 * f, "height_mm": 6.0 * f},
        "mesh": {"nr": 8, "nz": 5, "element": "q1p0"},
        "remesh": {"quality_below": 0.3, "element_size_mm": 0.5, "die_size_ratio": 0.5,
                   "elements_across": 2, "onto_dies": True},
        "material": {"preset": "al1100_coupled"},
        "die": {"speed_mm_s": 10.0, "reduction": 0.4},
        "friction": {"model": "shear", "m": 0.3},
        "thermal": {"model": "coupled", "billet_temperature_K": 673.0,
                    "die_temperature_K": 473.0, "air_temperature_K": 293.15,
                    "htc_die_W_m2K": 10000.0, "htc_air_W_m2K": 20.0, "emissivity": 0.1},
        "time": {"dt_s": 0.02},
        "solver": {"max_cutbacks": 8},
        "output": {"fields": False, "plots": False},
        "process": {"operation": [
            blocker, {"kind": "dwell", "name": "transfer", "time_s": 0.25, "dt_s": 0.25}]},
    }  # fmt: skip


def test_a_part_in_air_only_springs_back():
    """In air the part only springs back and cools: over the dwell no node moves more than
    5 um from where the blocker left it (reference: 1.45 um of spring-back, the step's
    root from the part itself, ~1.4 um with 0.99 x the billet), no corner's quality falls
    by more than 1e-3, and the dwell's step is one of 0.25 s.  Before jaxform.process ran
    its first step in air without a probe, the 0.25 s step from the probe's extrapolated
    predictor failed, and its cutback converged with the part's top outer corner rolled
    over (0.28 mm up and inward at 0.125 s, quality 0.98 -> 0.79), which then flowed on
    at ~4 mm/s until the elements folded."""
    res = run(_blocker_then_air())
    dwell = res.runs[1].result
    lay = dwell.scene.model.layout
    moved = max(float(np.abs(lay.nodal(np.asarray(x))[:, :2]).max()) for x in dwell.fields["x"])
    assert moved < 5e-3, f"{1e3 * moved:.1f} um"
    quality = dwell.history["mesh_quality"]
    assert quality.min() > quality[0] - 1e-3
    np.testing.assert_allclose(dwell.history["time_s"], [0.0, 0.25], rtol=0, atol=1e-12)


def test_process_outputs_and_a_die_into_the_incoming_part(tmp_path):
    """The ParaView series has one entry per history row, time over the process; the
    process and per-blow plots are written; a die that overlaps the part the first blow
    left (flat at z = 3.0 mm, the part's top at 3.375 mm) is refused when the operation
    starts, with one line naming the operation and key."""
    from jaxform.plot import process_history
    from jaxform.process_outputs import operation_table, summary

    res = process()
    pvd = jaxform.io.write_vtu_series(tmp_path, res)
    text = pvd.read_text()
    assert text.count("<DataSet") == len(res.history["time_s"])
    process_history(res.history, {1: "first", 2: "second", 3: "cut"}, tmp_path / "p.png", "t")
    assert (tmp_path / "p.png").stat().st_size > 0
    table = operation_table(res)
    np.testing.assert_allclose(table["end_s"], [10.0, 14.0, 14.0], rtol=1e-12)
    assert len(summary(res)) == 3
    low = {"kind": "forming", "name": "low", "travel_mm": 0.1,
           "die": {"profile_mm": [[0.0, 3.0], [6.0, 3.0]]}}  # fmt: skip
    with pytest.raises(ConfigError, match=r"process.operation\[2\] \(low\): die.profile_mm"):
        run(seed_document([FIRST, low]))


def _write(tmp_path, operations, **sections) -> str:
    doc = seed_document(operations)
    for name, table in sections.items():
        doc.setdefault(name, {}).update(table)
    import tomli_w

    path = tmp_path / "process.toml"
    path.write_bytes(tomli_w.dumps(doc).encode())
    return str(path)


BAD = [
    ([{"kind": "forming", "travel_mm": 0.3}], {}, "process.operation[1] (forming): a forming "
     "operation needs its own dies"),
    ([FIRST, {"kind": "forming", "name": "second", "die": {}}], {},
     "process.operation[2] (second): give exactly one stroke"),
    ([FIRST, {"kind": "dwell", "name": "wait"}], {}, "process.operation[2] (wait): missing "
     "required key time_s"),
    ([FIRST, {"kind": "trim"}], {}, "process.operation[2] (trim): missing required key radius_mm"),
    ([FIRST, {"kind": "reheat", "set_temperature_K": 700.0}], {},
     "process.operation[2] (reheat): a reheat needs thermal.model"),
    ([{"kind": "dwell", "time_s": 1.0}], {}, "needs at least one forming operation"),
    ([{"kind": "dwell", "time_s": 1.0}, FIRST], {}, "process.operation[1] (dwell): kind = "
     "'dwell': a process starts with a forming operation"),
    ([FIRST, {"kind": "press"}], {}, "process.operation[2] (?): kind = 'press'"),
    ([FIRST, {"kind": "forming", "name": "deep", "travel_mm": 0.2,
              "die": {"profile_mm": [[0.0, 3.4], [6.0, 3.4]]}},
      {"kind": "forming", "name": "deeper", "travel_mm": 0.2,
       "die": {"profile_mm": [[0.0, 3.1], [6.0, 3.1]]}}], {},
     "process.operation[3] (deeper): die.profile_mm reaches below"),
    ([FIRST, {"kind": "forming", "name": "f", "travel_mm": 0.2, "die": {"speed_mm_s": -1.0}}],
     {}, "process.operation[2] (f): die.speed_mm_s = -1.0"),
    ([FIRST, {"kind": "dwell", "time_s": 1.0, "speed": 2}], {}, "unknown key 'speed'"),
]  # fmt: skip


@pytest.mark.parametrize("operations, sections, needle", BAD)
def test_bad_process_refused_in_one_line(tmp_path, operations, sections, needle):
    """Each bad process is refused before anything compiles (the CLI harness stubs every
    compiling entry point): exit 2, one stderr line naming the operation and key."""
    path = _write(tmp_path, operations, **sections)
    assert_refused(["run", path, "--out", str(tmp_path / "out")], needle)


def test_trim_of_a_ring_inside_its_bore_refused(tmp_path):
    """A trim radius inside a ring's bore would remove the whole part: exit 2, one line."""
    doc = {
        "ring": {"outer_diameter_mm": 18.0, "inner_diameter_mm": 9.0, "height_mm": 6.0},
        "mesh": {"nr": 3, "nz": 3},
        "die": {"speed_mm_s": 0.1, "reduction": 0.1},
        "time": {"dt_s": 1.0},
        "process": {"operation": [FIRST, {"kind": "trim", "name": "cut", "radius_mm": 4.0}]},
    }
    import tomli_w

    path = tmp_path / "ring.toml"
    path.write_bytes(tomli_w.dumps(doc).encode())
    needle = "process.operation[2] (cut): radius_mm = 4: the part starts at r = 4.5"
    assert_refused(["run", str(path), "--out", str(tmp_path / "o")], needle)


def test_shipped_process_config_is_valid():
    """configs/two_stage_disk.toml validates (the blocker, the transfer, the finisher
    with its flash land) and its dies clear each other (no compile)."""
    from jaxform.process import prepare
    from jaxform.process_config import load_document, operations

    ops = operations(load_document("configs/two_stage_disk.toml"))
    prepare(ops)
    assert [op.kind for op in ops] == ["forming", "dwell", "forming", "trim"]
    assert ops[2].config.die.part_radius_mm == 6.4
    assert ops[0].config.thermal.model == "coupled"


jaxform.enable_x64()


def test_carry_is_one_fixed_map_for_numpy_and_jax():
    """The map that carried the part into the cone die's blow (jaxform.process.Carry)
    gives the same state applied to NumPy values and to JAX values (exactly), as a
    gradient run will apply it; the new reference is the old deformed positions."""
    import jax
    import jax.numpy as jnp

    res, first = process(), single()
    carry = res.runs[1].transfer
    state = jax.tree_util.tree_map(np.asarray, first.final_state)
    coords = np.asarray(first.final_scene.inputs.coords)
    host, pos = carry.apply(state, coords)
    traced, pos_j = jax.jit(lambda s, c: carry.apply(s, c, jnp))(state, coords)
    for a, b in zip(jax.tree_util.tree_leaves(host), jax.tree_util.tree_leaves(traced)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    np.testing.assert_allclose(pos, positions(first.final_scene, state.x), rtol=0, atol=1e-15)
    np.testing.assert_array_equal(np.asarray(pos_j), pos)
    np.testing.assert_array_equal(np.asarray(res.runs[1].result.scene.inputs.coords), pos)
