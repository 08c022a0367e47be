"""Coupled thermo-mechanics (thermal.model = 'coupled', :mod:`jaxform.heat`): each test names
its reference and tolerance."""

from dataclasses import replace
from functools import cache

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from fd_check import jacobian_fd_error
from thermal_series import cylinder_theta, slab_theta

from jaxform.config import load_config
from jaxform.errors import ConfigError
from jaxform.materialpoint import Ram, uniaxial_compression
from jaxform.postprocess import HEAT_COLUMNS, nodal_temperature, nodal_volumes, positions
from jaxform.scenes import build_scene
from jaxform.simulation import simulate
from jaxform.stepping import step_context

SEED = {
    "billet": {"diameter_mm": 5.0, "height_mm": 7.5},
    "mesh": {"nr": 3, "nz": 3},
    "die": {"speed_mm_s": 0.075, "reduction": 0.3},
    "time": {"dt_s": 1.0},
    "thermal": {"model": "coupled"},
    "output": {"fields": False, "plots": False},
}
# no heat leaves: the billet keeps its plastic work
ADIABATIC = ("thermal.htc_die_W_m2K=0.0", "thermal.htc_air_W_m2K=0.0", "thermal.emissivity=0.0")
# die chill at forging speed, shear friction, radiation: every heat term at work
CHILL = ("material.preset=al1100_coupled", "thermal.die_temperature_K=473.0",
         "friction.model=shear", "friction.m=0.3", "die.speed_mm_s=7.5", "time.dt_s=0.01",
         "die.reduction=0.2", "thermal.emissivity=0.5")  # fmt: skip


def scene(base, *overrides):
    return build_scene(load_config(base, list(overrides)))


@cache
def run(*overrides):
    sc = scene(SEED, *overrides)
    return sc, simulate(sc)


def test_adiabatic_upsetting_heats_by_the_plastic_work():
    """Frictionless upsetting, no heat loss: the temperature stays uniform (1e-9 relative
    spread) and rises by beta x plastic work / (rho c), the work integrated at the material
    point with the same steps (jaxform.materialpoint: sum of J sigma_eq d_eqps per
    reference volume), to 1e-6 relative."""
    sc, res = run(*ADIABATIC)
    h, th = res.history, sc.inputs.thermal
    law, params = sc.model.law, sc.inputs.params
    mp = jax.jit(
        lambda t: uniaxial_compression(
            law, params, final_strain=1.0, n_steps=1, ram=Ram(0.075, 7.5), times_s=t
        )
    )(jnp.asarray(h["time_s"][1:]))
    lam_r, sig, eqps = (np.asarray(mp[k]) for k in ("lateral_stretch", "stress_MPa", "eqps"))
    lam_z = 1.0 - 0.075 * np.asarray(mp["time_s"]) / 7.5
    work = np.cumsum(lam_r[1:] ** 2 * lam_z[1:] * sig[1:] * np.diff(eqps))  # mJ/mm^3 of V0
    rise = float(th.taylor_quinney) * work / float(th.capacity)
    temps = np.stack([nodal_temperature(sc, x) for x in res.fields["x"][1:]])
    assert np.ptp(temps, axis=1).max() <= 1e-9 * 673.0
    got = temps.mean(axis=1) - 673.0
    assert rise[-1] > 1.0  # a rise worth checking (K)
    assert np.max(np.abs(got - rise) / rise) <= 1e-6, np.max(np.abs(got - rise) / rise)
    # the heat columns: plastic heat = stored heat = rho c V0 x rise, nothing lost
    volume = nodal_volumes(sc).sum()
    stored = h["heat_stored_mJ"][-1]
    assert abs(stored / (float(th.capacity) * volume * rise[-1]) - 1.0) <= 1e-6
    assert abs(h["heat_plastic_mJ"][-1] / stored - 1.0) <= 1e-8
    assert h["heat_to_dies_mJ"][-1] == 0.0 and h["heat_to_air_mJ"][-1] == 0.0
    assert np.allclose(h["mean_temperature_K"][1:], temps.mean(axis=1), rtol=1e-12)


def test_energy_balance_every_step():
    """Die chill with friction, convection and radiation: in every step the heat stored
    equals the plastic heat minus what the dies and the air take, to 1e-8 of the largest
    term (the assembled thermal rows sum to that balance; Newton stops at rtol 1e-10)."""
    sc, res = run(*CHILL)
    h = res.history
    d = {k: np.diff(h[k]) for k in HEAT_COLUMNS}
    balance = d["heat_stored_mJ"] - (
        d["heat_plastic_mJ"] - d["heat_to_dies_mJ"] - d["heat_to_air_mJ"]
    )
    largest = np.max(np.abs(np.stack(list(d.values()))), axis=0)
    assert np.all(d["heat_to_dies_mJ"] > 0) and np.all(d["heat_to_air_mJ"] > 0)
    assert np.all(d["heat_plastic_mJ"] > 0)
    assert np.max(np.abs(balance) / largest) <= 1e-8
    # the stored heat is the capacity-weighted temperature change
    th = sc.inputs.thermal
    w = nodal_volumes(sc)
    t0, t1 = (nodal_temperature(sc, res.fields["x"][k]) for k in (0, -1))
    stored = float(th.capacity) * np.sum(w * (t1 - t0))
    assert abs(stored / h["heat_stored_mJ"][-1] - 1.0) <= 1e-10
    # die chill: the contact zone is the coldest, and colder than the mean
    top = sc.mesh.node_sets["top"]
    temps = nodal_temperature(sc, res.fields["x"][-1])
    assert temps[top].min() == temps.min() < h["mean_temperature_K"][-1] < 673.0


def test_isothermal_limits_reproduce_the_isothermal_history():
    """thermal.model = 'none' is the isothermal run; a coupled run whose heat capacity is
    made 1e12 x larger keeps 673 K, so with the Arrhenius preset al1100_coupled (equal to
    the lumped al1100_673K at 673 K) its force history equals the isothermal one to 1e-8."""
    iso = simulate(scene(SEED, "thermal.model=none", "die.reduction=0.1"))
    assert "mean_temperature_K" not in iso.history
    sc = scene(SEED, "material.preset=al1100_coupled", "die.reduction=0.1",
               "thermal.die_temperature_K=473.0")  # fmt: skip
    th = sc.inputs.thermal
    th = replace(th, density_kg_m3=th.density_kg_m3 * 1e12)
    sc = replace(sc, inputs=replace(sc.inputs, thermal=th))
    res = simulate(sc)
    f_iso, f = iso.history["force_N"][1:], res.history["force_N"][1:]
    assert np.max(np.abs(f - f_iso) / f_iso) <= 1e-8
    assert np.max(np.abs(res.history["max_temperature_K"] - 673.0)) <= 1e-8


def test_config_needs_thermal_properties_for_a_coupled_run():
    """A preset without a [thermal] table (the J2 verification material) cannot run coupled
    unless the config gives the properties: one line naming the key."""
    with pytest.raises(ConfigError, match="material.density_kg_m3"):
        load_config(SEED, ["material.preset=j2_perfect_100MPa"])
    cfg = load_config(SEED, ["material.preset=j2_perfect_100MPa", "material.density_kg_m3=7800.0",
                             "material.specific_heat_J_kgK=460.0",
                             "material.conductivity_W_mK=45.0"])  # fmt: skip
    assert cfg["material"]["density_kg_m3"] == 7800.0
    seed = load_config(SEED, ["thermal.model=none"])
    assert seed["material"]["specific_heat_J_kgK"] == 904.0  # recorded from the preset


def test_thermal_jacobian_against_finite_differences():
    """The assembled Jacobian with the thermal rows and the thermo-mechanical coupling
    (Arrhenius material, plastic heating, die chill, radiation) against 4-point central
    differences: relative error (Frobenius) <= 1e-6."""
    sc, res = run(*CHILL)
    st = res.final_state
    rng = np.random.default_rng(2)
    x = st.x + 1e-4 * jnp.asarray(rng.standard_normal(st.x.shape)) * (st.x != 0)
    ctx = step_context(sc.model, st, sc.inputs, sc.idx, st.t + 0.005, 0.005)
    assert float(jnp.sum(ctx.heat.touch)) > 0  # the die chill is in the rows
    err = jacobian_fd_error(sc, x, ctx, h_rel=1e-6)
    assert err <= 1e-6, err


# conduction alone: a body pressed by 5e-9 mm (no heating, taylor_quinney = 0), its top
# touching the die (a Robin boundary to the die temperature, or adiabatic with h_die = 0),
# its side in still air (a Robin boundary, or adiabatic with h_air = 0)
CONDUCTION = {
    "mesh": {"element": "q1p0"},
    "die": {"speed_mm_s": 1e-6, "reduction": 5e-9},
    "thermal": {"model": "coupled", "billet_temperature_K": 673.0, "air_temperature_K": 293.0,
                "die_temperature_K": 293.0, "emissivity": 0.0, "taylor_quinney": 0.0},
    "output": {"fields": False, "plots": False},
}  # fmt: skip
K_W_MK, RHO_C = 222.0, 2710.0 * 904.0 * 1e-6  # mW/(mm K), mJ/(mm^3 K): the preset's
ALPHA = K_W_MK / RHO_C  # mm^2/s


def conduction_run(geometry, n, dt_s, htc_die, htc_air, size):
    cfg = dict(CONDUCTION, mesh=dict(CONDUCTION["mesh"], geometry=geometry, nr=n[0], nz=n[1]),
               billet={"diameter_mm": 2.0 * size[0], "height_mm": 2.0 * size[1]},
               time={"dt_s": dt_s})  # fmt: skip
    cfg["thermal"] = dict(cfg["thermal"], htc_die_W_m2K=htc_die, htc_air_W_m2K=htc_air)
    sc = scene(cfg)
    return sc, simulate(sc)


def theta_error(sc, res, coordinate, reference, length):
    """Largest |theta_FE - theta_series| over the nodes at 1/4, 1/2 and the end of the run,
    where theta = (T - 293) / (673 - 293) and the series takes (coordinate / length, Fo)."""
    errs = []
    times = res.history["time_s"]
    for k in (len(times) // 4, len(times) // 2, len(times) - 1):
        theta = (nodal_temperature(sc, res.fields["x"][k]) - 293.0) / 380.0
        pos = positions(sc, res.fields["x"][k])[:, coordinate]
        ref = reference(pos / length, ALPHA * times[k] / length**2)
        errs.append(np.max(np.abs(theta - ref)))
    return max(errs)


def test_slab_cooling_against_the_series_solution():
    """Plane slab, half-thickness 1 mm, Bi = 1 (h = 222 kW/m^2 K to a die at 293 K, the
    mid-plane adiabatic), up to Fo = 0.9: the nodal theta within 1 % (0.01) of the series
    solution (tests/thermal_series.py) on 12 elements with dt = 1e-4 s."""
    sc, res = conduction_run("plane_strain", (1, 12), 1e-4, 222000.0, 0.0, (0.5, 1.0))
    assert res.history["time_s"][-1] == pytest.approx(0.01, rel=1e-9)
    err = theta_error(sc, res, 1, lambda x, fo: slab_theta(x, fo, 1.0), 1.0)
    assert err <= 0.01, err


def test_cylinder_cooling_against_the_series_solution():
    """Infinite cylinder, radius 1 mm, Bi = 1 (h = 222 kW/m^2 K to air at 293 K; the top
    touches a die with h_die = 0, the mid-plane adiabatic), up to Fo = 0.9: nodal theta
    within 1 % (0.01) of the Bessel series (tests/thermal_series.py) on 12 elements."""
    sc, res = conduction_run("axisymmetric", (12, 1), 1e-4, 0.0, 222000.0, (1.0, 0.25))
    err = theta_error(sc, res, 0, lambda r, fo: cylinder_theta(r, fo, 1.0), 1.0)
    assert err <= 0.01, err


@pytest.mark.slow
def test_conduction_converges_under_refinement():
    """Slab and cylinder on 4, 8 and 16 elements with dt ~ h^2 (backward Euler's O(dt)
    error then falls like the O(h^2) of the bilinear elements): the error against the
    series falls by >= 3x per halving of h."""
    for geometry, size, cells, htc, ref, axis in (
        ("plane_strain", (0.5, 1.0), lambda n: (1, n), (222000.0, 0.0),
         lambda x, fo: slab_theta(x, fo, 1.0), 1),
        ("axisymmetric", (1.0, 0.25), lambda n: (n, 1), (0.0, 222000.0),
         lambda r, fo: cylinder_theta(r, fo, 1.0), 0),
    ):  # fmt: skip
        errs = []
        for n in (4, 8, 16):
            sc, res = conduction_run(geometry, cells(n), 4e-4 * (4 / n) ** 2, *htc, size)
            errs.append(theta_error(sc, res, axis, ref, 1.0))
        assert errs[0] / errs[1] >= 3.0 and errs[1] / errs[2] >= 3.0, (geometry, errs)


@pytest.mark.slow
def test_thermal_gradients_against_central_differences_and_taylor():
    """Design group 'thermal' (billet and die temperature, log die conductance,
    Taylor-Quinney factor) on a coupled 3 x 3 scene with die chill and shear friction,
    objective the forging work: each component of the reverse-mode gradient against
    central differences (h = 1e-4, relative 1e-5; measured <= 2e-8), and the Taylor
    remainders converge at second order (rates >= 1.9; measured 2.00)."""
    from jaxform.design import build_problem, taylor_test
    from jaxform.design.objectives import ForgingWork

    sc = scene(SEED, "material.preset=al1100_coupled", "mesh.element=q1p0",
               "thermal.die_temperature_K=473.0", "thermal.emissivity=0.5",
               "friction.model=shear", "friction.m=0.3", "die.speed_mm_s=7.5",
               "time.dt_s=0.03")  # fmt: skip
    pb = build_problem(sc, groups=("thermal",), objective=ForgingWork(), single_program=True)
    _, grad, _ = pb.value_and_grad(pb.start)
    u = np.asarray(pb.start["thermal"])
    h = 1e-4
    for i in range(4):
        du = np.eye(4)[i]
        plus, minus = (float(pb.value({"thermal": u + s * h * du})[0]) for s in (1.0, -1.0))
        fd, exact = (plus - minus) / (2 * h), float(np.asarray(grad["thermal"])[i])
        assert exact != 0.0 and abs(fd - exact) <= 1e-5 * abs(exact), (i, fd, exact)
    (row,) = taylor_test(pb)
    assert row.min_rate >= 1.9, row.rate1


def test_dwell_in_air_cools_as_the_lumped_body():
    """thermal.dwell_s = 1 s before the dies move: the die force stays 0 (1e-8 N) and the
    heat to the dies 0, and the mean temperature follows the lumped-capacitance ODE rho c V dT/dt =
    -A (h (T - T_air) + eps sigma (T^4 - T_air^4)) (Bi = 2e-4; SciPy Radau, rtol 1e-10;
    A = side + top of the half model) within 0.5 % of the temperature drop (backward
    Euler with 10 steps)."""
    from scipy.integrate import solve_ivp

    sc, res = run("thermal.dwell_s=1.0", "time.dt_s=0.1", "die.reduction=0.02",
                  "thermal.emissivity=0.8", "thermal.htc_air_W_m2K=50.0",
                  "thermal.die_path_time_s=[0.0, 1.0, 2.0]",
                  "thermal.die_path_change_K=[0.0, -100.0, -300.0]")  # fmt: skip
    h, th = res.history, sc.inputs.thermal
    dwell = h["time_s"] <= 1.0 + 1e-12
    assert dwell.sum() == 11 and np.max(np.abs(h["force_N"][dwell])) <= 1e-8  # N
    assert np.all(h["heat_to_dies_mJ"][dwell] == 0.0) and h["heat_to_dies_mJ"][-1] != 0.0
    r, hh = 2.5, 3.75
    area, volume = 2 * np.pi * r * hh + np.pi * r**2, np.pi * r**2 * hh

    def rate(t, y):
        flux = 1e-3 * (50.0 * (y - 293.15) + 0.8 * 5.670374419e-8 * (y**4 - 293.15**4))
        return -area * flux / (float(th.capacity) * volume)

    ode = solve_ivp(rate, (0.0, 1.0), [673.0], method="Radau", rtol=1e-10, atol=1e-10)
    drop_ode = 673.0 - ode.y[0, -1]
    drop = 673.0 - h["mean_temperature_K"][dwell][-1]
    assert drop_ode > 5.0 and abs(drop / drop_ode - 1.0) <= 5e-3, (drop, drop_ode)
    # the die temperature path: 673 K, 573 K at 1 s, 373 K at 2 s, linear between, held after
    t_die = [float(th.die_temperature(t)) for t in (0.0, 0.5, 1.0, 1.5, 2.0, 3.0)]
    assert np.allclose(t_die, [673.0, 623.0, 573.0, 473.0, 373.0, 373.0], rtol=0, atol=1e-12)
    # once the dies touch, they take heat: the billet is hotter than them
    d_die = np.diff(h["heat_to_dies_mJ"])[~dwell[1:]]
    assert np.all(d_die > 0)


def test_outputs_carry_the_temperature(tmp_path):
    """The files a user reads: history.csv has the temperature and heat columns, the
    ParaView series a temperature_K point field, temperature.png is drawn, and the
    resolved config.toml records the material's thermal values.  Reference: the
    adiabatic run, whose temperature is uniform and known (first test), to 1e-9 K (1e-7 K
    in the CSV's 10 digits)."""
    import tomllib

    import meshio

    from jaxform.driver import write_outputs
    from jaxform.io import read_csv

    sc, res = run(*ADIABATIC)
    out_cfg = replace(sc.settings.output, fields=True, plots=True)
    res = replace(res, scene=replace(sc, settings=replace(sc.settings, output=out_cfg)))
    write_outputs(tmp_path, res)
    temps = nodal_temperature(sc, res.fields["x"][-1])
    hist = read_csv(tmp_path / "history.csv")
    assert abs(hist["mean_temperature_K"][-1] - temps.mean()) <= 1e-7  # 10 digits in CSV
    assert set(HEAT_COLUMNS) <= set(hist)
    last = sorted((tmp_path / "fields").glob("*.vtu"))[-1]
    field = meshio.read(last).point_data["temperature_K"]
    assert np.max(np.abs(field - temps)) <= 1e-9 and temps.mean() > 673.0 + 1.0
    assert (tmp_path / "temperature.png").stat().st_size > 10_000
    cfg = tomllib.loads((tmp_path / "config.toml").read_text())
    assert cfg["material"]["density_kg_m3"] == 2710.0
    assert cfg["material"]["specific_heat_J_kgK"] == 904.0
    assert cfg["thermal"]["model"] == "coupled"


def test_j2_yield_stress_follows_the_temperature(tmp_path):
    """A J2 material file with yield_slope_MPa_K = -0.1 (reference 293.15 K) and a
    [thermal] table, the billet at 493.15 K (sigma_y = 100 - 20 = 80 MPa), its heat
    capacity made 1e12 x larger (the temperature stays put): frictionless upsetting flows
    at 80 MPa, so the force is 80 MPa x the current area, to 1e-6.  Reference: J2's yield
    condition."""
    material = tmp_path / "j2_hot.toml"
    material.write_text(
        'law = "j2"\n[params]\nG_MPa = 26000.0\nK_MPa = 68000.0\nsigma_y0_MPa = 100.0\n'
        "H_MPa = 0.0\nyield_slope_MPa_K = -0.1\nreference_temperature_K = 293.15\n"
        "[thermal]\ndensity_kg_m3 = 2700.0\nspecific_heat_J_kgK = 900.0\n"
        "conductivity_W_mK = 200.0\n"
    )
    sc = scene(SEED, f"material.preset={material}", "thermal.billet_temperature_K=493.15",
               "die.reduction=0.05", "time.dt_s=5.0", *ADIABATIC)  # fmt: skip
    th = sc.inputs.thermal
    th = replace(th, density_kg_m3=th.density_kg_m3 * 1e12)
    res = simulate(replace(sc, inputs=replace(sc.inputs, thermal=th)))
    r = positions(sc, res.fields["x"][-1])[sc.mesh.node_sets["side"], 0].mean()
    expected = 80.0 * np.pi * r**2
    assert abs(res.history["force_N"][-1] / expected - 1.0) <= 1e-6, (
        res.history["force_N"][-1],
        expected,
    )


def test_rezoning_carries_the_temperature():
    """Rezoning (mesh.rezone_quality, the relocation of the structured grid) carries the
    nodal temperature like the pressure: a temperature linear in the current position,
    T = 650 + 4 r - 3 z (K), on a distorted 6 x 6 billet is the same linear function of
    the rezoned positions to 1e-10 K (isoparametric interpolation reproduces linear
    fields)."""
    from jaxform.rezone import min_quality, rezone
    from jaxform.simulation import init

    sc = scene(SEED, "mesh.nr=6", "mesh.nz=6", "mesh.rezone_quality=0.5")
    state, _ = init(sc)
    lay, coords = sc.model.layout, np.asarray(sc.inputs.coords)
    rng = np.random.default_rng(4)
    inner = np.setdiff1d(np.arange(lay.n_nodes), np.concatenate(list(sc.mesh.node_sets.values())))
    u = np.zeros_like(coords)
    u[inner] = rng.uniform(-0.15, 0.15, (len(inner), 2))
    pos = coords + u
    x = np.array(state.x)
    nodal = lay.nodal(x)
    nodal[:, :2] = u
    nodal[:, lay.temperature_column] = 650.0 + 4.0 * pos[:, 0] - 3.0 * pos[:, 1] - 673.0
    state = replace(state, x=jnp.asarray(x))
    new, inputs, report = rezone(sc, state, sc.inputs)
    assert report.improved and report.quality_after > report.quality_before
    new_pos = np.asarray(inputs.coords)
    assert min_quality(new_pos, np.asarray(sc.mesh.elements)) == pytest.approx(report.quality_after)
    temps = 673.0 + lay.nodal(np.asarray(new.x))[:, lay.temperature_column]
    expected = 650.0 + 4.0 * new_pos[:, 0] - 3.0 * new_pos[:, 1]
    assert np.max(np.abs(temps - expected)) <= 1e-10
