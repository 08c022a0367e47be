"""Damage, die wear and flow lines (issue 40 parts 1-3), each where its value is known.

References:
* a homogeneous material point (jaxform.materialpoint): in uniaxial tension the stress is
  uniaxial at every step, so normalized Cockcroft-Latham and Brozzo equal the plastic
  strain and Ayada a third of it (1e-9 relative: the lateral traction is zero to the
  driver's Newton tolerance); in uniaxial compression the largest principal stress is 0,
  so C-L and Brozzo are 0 (1e-12 absolute) and Ayada is -eqps / 3;
* frictionless upsetting of the seed billet (Coulomb mu = 0) is exactly homogeneous: its
  pressure is the material point's stress p(t) at every radius, the radial slip of the
  material at radius rho over a step is rho (1 - R_n / R_n+1) (R the billet radius, the
  material point's lateral stretch), so Archard's wear at die radius rho in closed form is
  sum over steps of K p_n+1 (rho (1 - R_n / R_n+1))^b dt^(1-b) / H^c for rho <= R_n+1
  (1e-8 relative; stations outside the contact get 0);
* in the same run material lines of constant z and constant r stay straight and scale
  with the billet, z = z0 h / h0 and r = r0 R / R0 (1e-9 mm), through two forced remeshes
  (the displacement is linear, which the interpolation and the transfer carry exactly);
* the barrelled upsetting scene (Coulomb 0.3): the hoop stress at the bulge's equator
  turns tensile, so damage is > 0 and largest on the free surface near the mid-plane.
"""

from dataclasses import replace
from functools import cache

import jax
import jax.numpy as jnp
import meshio
import numpy as np
import pytest

import jaxform
from jaxform.config import ConfigError, load_config, typed
from jaxform.damage import CRITERIA, integrands, largest_principal
from jaxform.driver import fields_written, write_outputs
from jaxform.flowlines import flow_lines, largest_turn, self_folds, straightness
from jaxform.host_memory import map_large_blocks
from jaxform.materialpoint import Ram, uniaxial_compression
from jaxform.postprocess import positions
from jaxform.scenes import build_scene
from jaxform.simulation import FIELD_KEYS
from jaxform.transfer import gauss_points
from jaxform.wear import WearInputs, node_wear

SEED = "configs/upsetting_seed.toml"
FRICTION = "configs/upsetting_friction.toml"
QUIET = ["output.plots=false", "output.fields=false"]
K, H = 1e-3, 2000.0


# Both runs are the frictional scene's one compiled program (Coulomb friction, q1p0, 4 x 4,
# wear on, remeshing every 5 steps): mu, the stroke and the step are inputs, not constants.
COMMON = QUIET + ["mesh.nr=4", "mesh.nz=4", "wear.on=true", f"wear.k={K}",
                  f"wear.hardness_MPa={H}", "output.flow_line_spacing_mm=0.5"]  # fmt: skip


@cache
def seed_remeshed():
    """The seed billet without friction (Coulomb mu = 0), 15 %, two remeshes, wear on."""
    return jaxform.run(FRICTION, COMMON + ["friction.mu=0", "die.reduction=0.15",
                                           "remesh.every_steps=5"])  # fmt: skip


@cache
def barrelled():
    """Coulomb 0.3, 30 % in 4 s steps on the first mesh's padded program (remeshing on,
    but not before step 100: the step program of seed_remeshed's first mesh)."""
    return jaxform.run(FRICTION, COMMON + ["die.reduction=0.3", "time.dt_s=4.0",
                                           "remesh.every_steps=100"])  # fmt: skip


def _material_point(sc, history=None, sign=1.0, times=None):
    t = jnp.asarray(history["time_s"][1:] if times is None else times)
    ram = Ram(0.075, 7.5) if times is None else None
    rate = 0.0 if ram is not None else -sign * 0.01
    return uniaxial_compression(sc.model.law, sc.inputs.params, final_strain=1.0, n_steps=1,
                                strain_rate_1_s=rate, ram=ram, times_s=t)  # fmt: skip


def test_damage_integrands_of_known_stress_states():
    """Uniaxial tension (1, 1, 1/3), compression (0, 0, -1/3), pure shear (1/sqrt 3, 2/3,
    0) to 1e-14; the closed-form largest principal stress equals numpy's eigvalsh on random
    tensors with in-plane shear to 1e-12; derivatives finite at repeated principal values
    and at zero stress."""
    s = 80.0
    for sig, want in (
        (np.diag([0.0, 0.0, s]), [1.0, 1.0, 1.0 / 3.0]),
        (np.diag([-s, 0.0, 0.0]), [0.0, 0.0, -1.0 / 3.0]),
        (np.array([[0.0, s, 0.0], [s, 0.0, 0.0], [0.0, 0.0, 0.0]]),
         [1.0 / np.sqrt(3.0), 2.0 / 3.0, 0.0]),
    ):  # fmt: skip
        assert np.allclose(integrands(jnp.asarray(sig)), want, atol=1e-14, rtol=0)
    rng = np.random.default_rng(0)
    a = rng.normal(size=(50, 3, 3)) * 100.0
    a[:, 0, 2] = a[:, 2, 0] = a[:, 1, 2] = a[:, 2, 1] = 0.0
    a = 0.5 * (a + np.swapaxes(a, 1, 2))
    assert np.allclose(largest_principal(jnp.asarray(a)), np.linalg.eigvalsh(a)[:, -1],
                       atol=1e-12, rtol=0)  # fmt: skip
    for sig in (np.diag([0.0, 0.0, s]), np.zeros((3, 3))):
        g = jax.grad(lambda t: jnp.sum(integrands(t)))(jnp.asarray(sig))
        assert np.all(np.isfinite(g))


def test_material_point_tension_and_compression():
    """C-L and Brozzo = eqps in tension (1e-9 rel.), = 0 in compression (1e-12 abs.);
    Ayada = +-eqps/3 (1e-9 rel.); 50 steps to 50 % strain at 0.01 /s."""
    sc = build_scene(load_config(SEED, ["mesh.nr=2", "mesh.nz=2"]))
    times = np.linspace(0.0, 50.0, 51)[1:]
    for sign in (1.0, -1.0):  # tension, compression
        mp = _material_point(sc, sign=sign, times=times)
        ep, dmg = np.asarray(mp["eqps"])[1:], np.asarray(mp["damage"])[1:]
        assert ep[-1] > 0.45
        if sign > 0:
            assert np.max(np.abs(dmg[:, 0] / ep - 1.0)) <= 1e-9
            assert np.max(np.abs(dmg[:, 1] / ep - 1.0)) <= 1e-9
        else:
            assert np.max(np.abs(dmg[:, :2])) <= 1e-12
        assert np.max(np.abs(3.0 * sign * dmg[:, 2] / ep - 1.0)) <= 1e-9


def test_homogeneous_upsetting_damage_wear_and_flow_lines_through_remeshes():
    """The frictionless run remeshed twice: compression everywhere (C-L max <= 1e-12, Ayada =
    -eqps/3 to 1e-9 rel.), the wear profile equals the closed form (1e-8 rel.), the flow
    lines are straight (1e-9 mm) and scale with the billet (1e-9 mm); the surface line (side
    and top) keeps its square corner, the only turn of any line: 90 deg (1e-9), no fold."""
    res = seed_remeshed()
    h = res.history
    assert list(np.nonzero(h["remeshed"])[0]) == [5, 10]
    assert np.max(np.abs(h["damage_cl_max"])) <= 1e-12
    dmg, ep = np.asarray(res.fields["damage"][-1]), np.asarray(res.fields["eqps"][-1])
    assert np.allclose(3.0 * dmg[..., 2], -ep, rtol=1e-9, atol=0)
    # wear in closed form, from the material point's stress and lateral stretch
    mp = _material_point(res.scene, h)
    p, radius = np.asarray(mp["stress_MPa"]), 2.5 * np.asarray(mp["lateral_stretch"])
    rho = np.asarray(res.scene.inputs.wear.stations[0][:, 0])
    ref = np.zeros_like(rho)
    for n in range(len(p) - 1):
        on = rho <= radius[n + 1] * (1.0 + 1e-12)
        ref += np.where(on, K * p[n + 1] * rho * (1.0 - radius[n] / radius[n + 1]) / H, 0.0)
    got = np.asarray(res.final_state.wear_mm[0])
    inside = ref > 0.0
    assert inside.sum() > 10 and (~inside).sum() > 10
    assert np.max(np.abs(got[inside] / ref[inside] - 1.0)) <= 1e-8
    assert np.max(np.abs(got[~inside])) <= 1e-12 * ref.max()
    # flow lines: straight, scaled with the billet, through both remeshes
    lines = flow_lines(res, 0.5)
    assert straightness(lines) <= 1e-9
    start = lines.points[0]
    for k in (4, 5, 6, len(h["time_s"]) - 1):  # before, at and after the first remesh, end
        pos = positions(res.scene_at(k), res.fields["x"][k])
        lam = pos.max(axis=0) / np.array([2.5, 3.75])
        assert np.max(np.abs(lines.points[k] - start * lam)) <= 1e-9
        assert abs(largest_turn(lines, 0.5, k) - 90.0) <= 1e-9
    assert list(lines.family).count(2) == 1 and not self_folds(lines, 0.5)


def test_barrelled_upsetting_damage_is_largest_at_the_free_equator():
    """Coulomb 0.3, 30 %, 4 x 4: C-L and Brozzo max > 1e-3, the C-L max at a
    Gauss point of an element on the free side (bulge) near the mid-plane (z <= 0.25 x the
    current half height); C-L never decreases (an integral of f >= 0, carried through the
    remesh to the transfer's accuracy: 1e-9 slack).  The flow lines bend into the barrel
    but none folds onto itself (no lap: every line turns by less than 150 deg within a
    spacing; measured 59 deg)."""
    res = barrelled()
    h = res.history
    pos = positions(res.final_scene, res.fields["x"][-1])
    r_max, half = pos[:, 0].max(), pos[:, 1].max()
    assert h["damage_cl_max"][-1] > 1e-3 and h["damage_brozzo_max"][-1] > 1e-3
    sc = res.final_scene
    gp = gauss_points(pos, np.asarray(sc.mesh.elements))
    where = np.array([h["damage_cl_r_mm"][-1], h["damage_cl_z_mm"][-1]])
    e = np.argmin(np.min(np.linalg.norm(gp - where, axis=2), axis=1))  # its element
    assert np.isin(sc.mesh.elements[e], sc.mesh.node_sets["side"]).any()  # on the free side
    assert where[0] >= 0.75 * r_max and where[1] <= 0.25 * half, (where, r_max, half)
    assert not res.remeshes and np.all(np.diff(h["damage_cl_max"]) >= -1e-15)
    lines = flow_lines(res, 0.5)
    assert not self_folds(lines, 0.5)


def test_a_lean_run_keeps_the_unknowns_of_every_row_and_the_rest_of_the_last():
    """``jaxform run`` (``lean``: the result holds for every row only the fields its
    outputs read, :func:`jaxform.driver.fields_written`; here without plots or ParaView
    fields, the unknowns) gives the same history to the last digit, damage columns
    included (computed as each row comes, before its damage field is let go), and the
    last row's every field: equal to the full run's."""
    full = barrelled()
    cfg = typed(load_config(FRICTION, COMMON + ["die.reduction=0.3",
                                           "time.dt_s=4.0", "remesh.every_steps=100"]))  # fmt: skip
    assert fields_written(cfg) == ("x",)
    lean = jaxform.run(cfg, lean=True)
    assert set(lean.history) == set(full.history)
    for k, v in full.history.items():
        np.testing.assert_array_equal(lean.history[k], v, err_msg=k)
    assert len(full.history["time_s"]) > 3 and any(k.startswith("damage_") for k in full.history)
    np.testing.assert_array_equal(lean.fields["x"], full.fields["x"])
    for k in FIELD_KEYS:
        assert len(lean.fields[k]) == (len(full.fields[k]) if k == "x" else 1), k
        np.testing.assert_array_equal(lean.fields[k][-1], full.fields[k][-1], err_msg=k)
    with pytest.raises(ValueError, match=r"keep_fields \['strain'\] are not output fields"):
        jaxform.simulate(full.scene, keep_fields=("x", "strain"))
    plotted = replace(cfg, output=replace(cfg.output, plots=True, animation=True))
    assert fields_written(plotted) == ("x", "eqps", "slip_mm", "contact_status")
    written = replace(cfg, output=replace(cfg.output, fields=True))
    assert fields_written(written) == FIELD_KEYS


def test_a_series_written_as_the_run_goes_equals_the_one_written_at_the_end(tmp_path):
    """The ParaView series ``jaxform run`` writes row by row (``lean``: each row's VTU as
    the run accepts it, through two remeshes: each row on its own mesh) is the series
    written at the end from every row's fields, file for file to the byte, and the lean
    result holds the stresses of the last row alone."""
    over = COMMON + ["friction.mu=0", "die.reduction=0.15", "remesh.every_steps=5",
                     "output.fields=true"]  # fmt: skip
    full = jaxform.run(FRICTION, over, out_dir=tmp_path / "full")
    lean = jaxform.run(FRICTION, over, out_dir=tmp_path / "lean", lean=True)
    assert len(lean.remeshes) == 2 and len(lean.fields["stress"]) == 1
    names = sorted(p.name for p in (tmp_path / "full" / "fields").glob("step_*.vtu"))
    assert len(names) == len(full.history["time_s"]) > 10
    for name in ["../fields.pvd"] + names:
        a = (tmp_path / "full" / "fields" / name).read_bytes()
        assert a == (tmp_path / "lean" / "fields" / name).read_bytes(), name
    assert sorted(p.name for p in (tmp_path / "lean" / "fields").glob("step_*.vtu")) == names


def test_the_command_line_maps_large_blocks():
    """The heap policy ``jaxform`` sets for its process (:mod:`jaxform.host_memory`):
    glibc accepts it here (the CI machine's C library)."""
    assert map_large_blocks()


def test_node_wear_exponents():
    """K p |s|^b dt^(1-b) for b = 2 (slip speed squared) and b = 1; 0 where p <= 0 or no
    slip (the hardness H^c divides at the stations); H(T) = 6000 - 5 (T - 293) MPa."""
    law = WearInputs(jnp.zeros((1, 2, 2)), jnp.asarray(1e-3), jnp.asarray([2.0]),
                     jnp.asarray(2.0), jnp.asarray(0.5))  # fmt: skip
    p, s, dt = jnp.asarray([10.0, -1.0, 5.0]), jnp.asarray([0.2, 0.3, 0.0]), 0.5
    assert np.allclose(node_wear(law, p, s, dt), [1e-3 * 10 * 0.04 / 0.5, 0.0, 0.0], rtol=1e-14)
    one = WearInputs(law.stations, law.k, law.hardness_MPa, jnp.asarray(1.0), law.c)
    assert np.allclose(node_wear(one, p, s, dt), [1e-3 * 10 * 0.2, 0.0, 0.0], rtol=1e-14)
    # hardness linear in the die temperature, at least 1 MPa
    hot = replace(law, hardness_MPa=jnp.asarray([6000.0]), slope_MPa_K=jnp.asarray(-5.0))
    assert np.allclose(hot.hardness(693.0), [4000.0], rtol=1e-14)
    assert np.allclose(hot.hardness(5000.0), [1.0], rtol=1e-14)


def test_outputs_written(tmp_path):
    """`write_outputs` with wear, flow lines and a critical damage value: wear_top.csv,
    wear.png, damage.png, flow_lines.png, flow_lines.pvd; the VTU cells carry the damage
    integrals and the flag."""
    res = seed_remeshed()
    out = replace(res.scene.settings.output, fields=True, plots=True, damage_critical=1e-9,
                  damage_criterion="ayada")  # fmt: skip
    res = replace(res, scene=replace(res.scene, settings=replace(res.scene.settings, output=out)))
    write_outputs(tmp_path, res)
    for name in ("wear_top.csv", "wear.png", "damage.png", "flow_lines.png", "flow_lines.pvd"):
        assert (tmp_path / name).stat().st_size > 200, name
    cells = meshio.read(tmp_path / "fields" / "step_00015.vtu").cell_data
    assert all(f"damage_{c}" in cells for c in CRITERIA) and "damage_flag" in cells
    lines = meshio.read(tmp_path / "fields" / "flow_lines_00015.vtu")
    assert lines.cells[0].type == "line" and len(lines.points) > 100


def test_wear_config_is_checked():
    with pytest.raises(ConfigError, match="wear.hardness_by_die_MPa"):
        load_config(SEED, ["wear.hardness_by_die_MPa=[-1.0]"])
    with pytest.raises(ConfigError, match="wear.b"):
        load_config(SEED, ["wear.b=0"])
    with pytest.raises(ConfigError, match="output.damage_criterion"):
        load_config(SEED, ["output.damage_criterion='oyane'"])


def test_flow_lines_are_located_again_after_a_rezoning():
    """A homogeneous stretch (r, z) -> (a_k r, b_k z) over 5 rows, the nodes rezoned after
    row 2 onto a graded distribution of the same material (r' = R0 (r / R0)^1.4): the lines
    follow the stretch exactly (1e-12 mm) because they are located again on the moved
    nodes; kept on their old natural coordinates they would be off by > 1e-2 mm."""
    from types import SimpleNamespace

    from jaxform.rezone import RezoneReport

    sc = build_scene(load_config(SEED, ["mesh.nr=3", "mesh.nz=3"]))
    lay, coords = sc.model.layout, np.asarray(sc.inputs.coords)
    graded = coords * [1.0, 1.0]
    graded[:, 0] = 2.5 * (coords[:, 0] / 2.5) ** 1.4
    a, b = np.array([1.0, 1.05, 1.1, 1.16, 1.2]), np.array([1.0, 0.9, 0.83, 0.75, 0.7])

    def x_of(material):  # unknowns whose displacement puts the nodes at F_k(material)
        out = []
        for k in range(5):
            x = np.zeros(lay.n_dofs)
            lay.nodal(x)[:, :2] = material * [a[k], b[k]] - coords
            out.append(x)
        return out

    xs = x_of(coords)[:3] + x_of(graded)[3:]
    report = RezoneReport(0.0, 0.5, 0.9, 0.0, True, graded * [a[2], b[2]])
    result = SimpleNamespace(history={"time_s": np.arange(5.0), "rezoned": [0, 0, 1, 0, 0]},
                             fields={"x": xs}, segments=[], rezones=[report], scene=sc,
                             scene_at=lambda k: sc)  # fmt: skip
    lines = flow_lines(result, 0.5)
    for k in range(5):
        assert np.max(np.abs(lines.points[k] - lines.points[0] * [a[k], b[k]])) <= 1e-12
    unmarked = {"time_s": np.arange(5.0), "rezoned": [0] * 5}  # the rezoning not told
    stale = flow_lines(SimpleNamespace(**{**vars(result), "history": unmarked, "rezones": []}),
                       0.5)  # fmt: skip
    assert np.max(np.abs(stale.points[4] - stale.points[0] * [a[4], b[4]])) > 1e-2


@pytest.mark.slow  # its own compiled program (two dies): ~1 min on 2 shared cores
def test_wear_of_mirrored_dies_is_the_same():
    """A full-height billet between the top die and its mirror image, closing
    symmetrically (Coulomb 0.3): the bottom die's wear profile (stations walked from the
    outside in) is the top die's reversed, to 1e-8 of its peak; both > 0."""
    over = QUIET + ["mesh.nr=3", "mesh.nz=6", "billet.full_height=true",
                    "bottom_die.mirror=true", "bottom_die.speed_share=0.5",
                    "die.reduction=0.2", "time.dt_s=3.0", "wear.on=true"]  # fmt: skip
    res = jaxform.run(FRICTION, over)
    top, bottom = np.asarray(res.final_state.wear_mm)
    assert top.max() > 0.0
    assert np.max(np.abs(top - bottom[::-1])) <= 1e-8 * top.max()
