"""Verification scenes (issue 6, item 1): Cook's membrane, Prandtl's flat punch, checkerboard.

Every test names its reference and tolerance.  Compiling a scene (~5-15 s on 2 cores)
costs far more than running it, so each (scene, element, mesh, theta) is built and run
once per module (``runs`` fixture) and the quick modes of the experiment scripts are
called in-process on the same meshes: they reuse the compiled programs.

References:
* Cook's membrane, linear (F = 1 N per mm depth, E = 250 MPa, nu = 0.4999): tip
  u_y = 0.077587 mm, the Richardson extrapolation of q1p0 and q1q1 on 32/64/128 meshes
  (experiments/cooks_membrane.py; the two elements agree to 3e-7 mm, observed order ~1.2).
* Cook's membrane, finite strain (F = 100 N, 10 steps, dead load): the same extrapolation.
* Prandtl: limit pressure (2 + pi) k, k = sigma_y / sqrt(3) (Prandtl 1920; Hill 1950 for
  the smooth punch), for a block wider than ~9 punch half-widths (here 11).
"""

import math
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest
from experiment_loader import experiment

from jaxform.config import ConfigError, load_config
from jaxform.element import facet_forces
from jaxform.loads import external_forces
from jaxform.postprocess import pressure_oscillation
from jaxform.scenes import build_scene
from jaxform.simulation import simulate

ROOT = Path(__file__).resolve().parents[1]
COOK = ROOT / "configs" / "cooks_membrane.toml"
PUNCH = ROOT / "configs" / "prandtl_punch.toml"
COOK_LINEAR_MM = 0.077587  # tip u_y at F = 1 N (linear compliance), see the module docstring
COOK_FINITE_MM = 6.7188  # tip u_y at F = 100 N (finite strain), see the module docstring
A_MM = 1.0625  # punch half-width in configs/prandtl_punch.toml
K_MPA = 100.0 / math.sqrt(3.0)  # shear yield stress of j2_rigid_plastic_100MPa
PRANDTL_MPA = (2.0 + math.pi) * K_MPA


@pytest.fixture(scope="module")
def runs():
    """runs(kind, element, *overrides) -> (scene, result), each built and run once."""
    cache = {}

    def get(kind, element, *overrides):
        key = (kind, element, overrides)
        if key not in cache:
            path = COOK if kind == "cook" else PUNCH
            cfg = load_config(
                path,
                [
                    f"mesh.element={element}",
                    "output.fields=false",
                    "output.plots=false",
                    *overrides,
                ],
            )
            sc = build_scene(cfg)
            cache[key] = (sc, simulate(sc))
        return cache[key]

    return get


def cook_tip(runs, element, n=32, *overrides):
    _, res = runs("cook", element, f"mesh.nr={n}", f"mesh.nz={n}", *overrides)
    return float(res.history["tip_uy_mm"][-1])


# ---------------------------------------------------------------------------------------
# Cook's membrane


def test_cook_q4_locks(runs):
    """q4 at nu = 0.4999 locks: at 32 x 32 the tip is below half the reference (measured
    0.37; 0.30 at 16 x 16, 0.52 at 64 x 64: refining relieves the locking only slowly)."""
    ratio = cook_tip(runs, "q4") / COOK_LINEAR_MM
    assert ratio < 0.5, ratio


@pytest.mark.parametrize("element", ["q1p0", "q1q1"])
def test_cook_mixed_elements_within_2_percent(runs, element):
    """q1p0 and q1q1 at 32 x 32 within 2 % of the reference (measured -1.0 % and -1.2 %;
    at 16 x 16 they are -2.3 % and -2.8 %)."""
    ratio = cook_tip(runs, element) / COOK_LINEAR_MM
    assert abs(ratio - 1.0) <= 0.02, ratio


def test_cook_finite_strain(runs):
    """F = 100 N in 10 steps (q1p0, 32 x 32, the same compiled program as F = 1 N): within
    2 % of the finite-strain reference (measured -0.7 %), and at least 10 % stiffer than
    100 x the linear compliance (7.76 mm): the geometric stiffening is there."""
    tip = cook_tip(runs, "q1p0", 32, "load.force_y_N=100", "time.dt_s=0.1")
    assert abs(tip / COOK_FINITE_MM - 1.0) <= 0.02, tip
    assert tip < 0.9 * 100.0 * COOK_LINEAR_MM, tip


def test_cook_traction_is_consistent(runs):
    """The traction on the loaded edge: resultant (0, F) (1e-12), every interior edge node
    F/16 x its two half-facet lengths, nothing elsewhere; the history's force_N is the
    applied load F t / t_ramp."""
    sc, res = runs("cook", "q1q1", "mesh.nr=32", "mesh.nz=32")
    assert abs(res.history["force_N"][-1] - 1.0) <= 1e-12
    lay = sc.model.layout
    f = np.asarray(
        external_forces(
            sc.inputs.load,
            1.0,
            sc.inputs.coords,
            sc.idx.load_facets,
            False,
            lay.n_fields,
            lay.n_dofs,
        )
    )
    fy = f[1 : lay.n_node_dofs : lay.n_fields]
    loaded = sc.mesh.node_sets["loaded"]
    assert abs(fy.sum() - 1.0) <= 1e-12 and np.all(f[0 :: lay.n_fields] == 0.0)
    assert np.all(np.delete(fy, loaded) == 0.0)
    ends = np.isin(loaded, [loaded.min(), loaded.max()])  # the two corners: half a facet
    np.testing.assert_allclose(fy[loaded][~ends], 1.0 / 32, rtol=1e-12)
    np.testing.assert_allclose(fy[loaded][ends], 0.5 / 32, rtol=1e-12)
    half = np.asarray(
        external_forces(
            sc.inputs.load,
            0.5,
            sc.inputs.coords,
            sc.idx.load_facets,
            False,
            lay.n_fields,
            lay.n_dofs,
        )
    )
    np.testing.assert_allclose(half, 0.5 * f, rtol=1e-15)


def test_facet_forces_are_the_consistent_integral():
    """Plane strain: L/2 per node; axisymmetric: 2 pi L (2 r_a + r_b)/6 and
    2 pi L (r_a + 2 r_b)/6 (exact integrals of the linear shape functions, 1e-14)."""
    xa, xb, t = jnp.array([1.0, 0.0]), jnp.array([4.0, 4.0]), jnp.array([0.3, -2.0])
    f = np.asarray(facet_forces(xa, xb, t, False))
    np.testing.assert_allclose(f, [[0.75, -5.0], [0.75, -5.0]], rtol=1e-14)
    f = np.asarray(facet_forces(xa, xb, t, True))
    w = 2.0 * np.pi * 5.0 * np.array([6.0, 9.0]) / 6.0
    np.testing.assert_allclose(f, w[:, None] * np.asarray(t)[None, :], rtol=1e-14)


@pytest.mark.slow
@pytest.mark.parametrize("element", ["q1p0", "q1q1"])
def test_cook_mixed_elements_converge(runs, element):
    """64 x 64: within 0.75 % of the reference (measured -0.42 % and -0.54 %; 32 x 32:
    -1.0 % and -1.2 %)."""
    ratio = cook_tip(runs, element, 64) / COOK_LINEAR_MM
    assert abs(ratio - 1.0) <= 0.0075, ratio


# ---------------------------------------------------------------------------------------
# checkerboard


def test_checkerboard_without_stabilization(runs):
    """q1q1 with theta = 0 (32 x 32 Cook's membrane): the nodal pressure is dominated by
    the checkerboard mode, oscillation measure > 0.8 (measured 0.92); the default theta =
    0.1 brings it below 0.2 (measured 0.13, the rest is the pressure singularity at the
    clamped corners) and at least 5 x lower."""
    sc0, r0 = runs("cook", "q1q1", "mesh.nr=32", "mesh.nz=32", "mesh.stabilization=0.0")
    sc1, r1 = runs("cook", "q1q1", "mesh.nr=32", "mesh.nz=32")
    assert sc1.model.formulation.theta == 0.1
    osc0 = pressure_oscillation(sc0, r0.fields["x"][-1])
    osc1 = pressure_oscillation(sc1, r1.fields["x"][-1])
    assert osc0 > 0.8, osc0
    assert osc1 < 0.2, osc1
    assert osc0 > 5.0 * osc1


def test_oscillation_measure_sees_a_checkerboard(runs):
    """The measure itself: exactly 1 for a pure +-1 checkerboard on the nodes of a
    structured mesh (element means 0), ~0 (< 0.05) for a linear field."""
    sc, res = runs("cook", "q1q1", "mesh.nr=32", "mesh.nz=32")
    x = np.array(res.fields["x"][-1])
    i, j = np.meshgrid(np.arange(33), np.arange(33))
    x[2 : sc.model.layout.n_node_dofs : 3] = ((-1.0) ** (i + j)).ravel()
    assert abs(pressure_oscillation(sc, x) - 1.0) <= 1e-12
    x[2 : sc.model.layout.n_node_dofs : 3] = 1.0 + 0.01 * np.asarray(sc.mesh.coords[:, 0])
    assert pressure_oscillation(sc, x) < 0.05


# ---------------------------------------------------------------------------------------
# Prandtl's punch


def punch_overrides(per_a):
    """m = per_a equal elements across the punch half-width, the corner mid-element (the
    experiment script's rule, so that its quick mode reuses these programs)."""
    return tuple(experiment("prandtl_punch").punch_overrides(per_a, A_MM))


def punch_ratio(runs, element, per_a, line_search=False):
    """p / ((2 + pi) k) per step.  Without line search Newton converges on the default-suite
    meshes to the same answer (1e-8; q1q1 and q1p0 with 1-2 cutbacks in the first steps) and
    the backtracking loop stays out of the compiled program (~2-5 s per program); q1p0 at
    a/h = 16.5 needs the line search (config default) in its first step."""
    _, res = runs(
        "punch", element, f"solver.line_search={str(line_search).lower()}", *punch_overrides(per_a)
    )
    return res.history["force_N"] / A_MM / PRANDTL_MPA


def test_punch_q1q1_limit_pressure_within_2_percent(runs):
    """q1q1 at a/h = 8.5: limit pressure (force / a at a travel of 0.0017 a) within 2 % of
    (2 + pi) k (measured +0.24 %; +0.33 % at a/h = 16.5 and 32.5), on a plateau: the last
    4 steps add < 0.5 % (measured 0.32 %)."""
    ratio = punch_ratio(runs, "q1q1", 8.5)
    assert abs(ratio[-1] - 1.0) <= 0.02, ratio[-1]
    assert ratio[-1] - ratio[-5] < 0.005, ratio[-5:]


def test_punch_q1p0_limit_pressure_coarse(runs):
    """Cheaper variant of the slow test below: q1p0 at a/h = 8.5 within 3 % of (2 + pi) k
    (measured -1.9 %: q1p0 approaches the limit from below, its error halving with h:
    -4.0, -1.9, -0.8, -0.3 % at a/h = 4.5, 8.5, 16.5, 32.5), on a plateau (last 4 steps
    < 0.5 %, measured 0.2 %)."""
    ratio = punch_ratio(runs, "q1p0", 8.5)
    assert abs(ratio[-1] - 1.0) <= 0.03, ratio[-1]
    assert ratio[-1] - ratio[-5] < 0.005, ratio[-5:]


@pytest.mark.slow
def test_punch_q1p0_limit_pressure_within_2_percent(runs):
    """q1p0 at a/h = 16.5 (2961 elements) within 2 % of (2 + pi) k (measured -0.8 %)."""
    ratio = punch_ratio(runs, "q1p0", 16.5, line_search=True)
    assert abs(ratio[-1] - 1.0) <= 0.02, ratio[-1]
    assert ratio[-1] - ratio[-5] < 0.005, ratio[-5:]


def test_punch_q4_overestimates(runs):
    """q4 locks under plastic incompressibility: at a/h = 4.5 the pressure exceeds
    (2 + pi) k by > 10 % (measured +27 %) and is still rising (> 3 % over the last 4 steps,
    measured 12 %): no limit load. Refining lowers it only slowly (+20, +14, +9 % at
    a/h = 8.5, 16.5, 32.5)."""
    ratio = punch_ratio(runs, "q4", 4.5)
    assert ratio[-1] > 1.10, ratio[-1]
    assert ratio[-1] - ratio[-5] > 0.03, ratio[-5:]


def test_punch_config_is_validated():
    """Block and membrane keys are checked before anything is compiled."""
    with pytest.raises(ConfigError, match=r"block.fine_width_mm = 20.0: must be <= block.width_mm"):
        load_config(PUNCH, ["block.fine_width_mm=20.0"])
    with pytest.raises(ConfigError, match=r"block.growth = 0.5: must lie in \(1, 3\]"):
        load_config(PUNCH, ["block.growth=0.5"])
    with pytest.raises(ConfigError, match=r"\[load\] does not apply to a \[block\] scene"):
        load_config(PUNCH, ["load.force_y_N=1.0"])
    with pytest.raises(ConfigError, match=r"membrane.corners_mm .* convex"):
        load_config(
            COOK, ["membrane.corners_mm=[[0.0, 0.0], [0.0, 44.0], [48.0, 60.0], [48.0, 44.0]]"]
        )
    with pytest.raises(ConfigError, match=r"load.edge = 'left': must differ"):
        load_config(COOK, ["load.edge=left"])
    with pytest.raises(ConfigError, match=r"\[die\] does not apply to a \[membrane\] scene"):
        load_config(COOK, ["die.reduction=0.5"])
    with pytest.raises(ConfigError, match=r"mesh.geometry = 'axisymmetric'"):
        load_config(COOK, ["mesh.geometry=axisymmetric"])


# ---------------------------------------------------------------------------------------
# experiment scripts, quick mode (same meshes as above: no new compilation)


def test_cooks_membrane_quick(runs, tmp_path):
    cook_tip(runs, "q4")  # make sure the programs exist whatever the test order
    out = experiment("cooks_membrane").main(["--quick", "--out", str(tmp_path)])
    rows = out["rows"]
    assert sorted(set(rows["element"])) == ["q1p0", "q1q1", "q4"]
    assert set(rows["load_N"]) == {1.0, 100.0}
    assert (tmp_path / "cooks_membrane.png").stat().st_size > 20_000
    assert len((tmp_path / "cooks_membrane.csv").read_text().splitlines()) == 1 + 6


def test_checkerboard_quick(runs, tmp_path):
    rows = experiment("checkerboard").main(["--quick", "--out", str(tmp_path)])
    assert rows["theta"] == [0.0, 0.1]
    assert rows["oscillation"][0] > 5.0 * rows["oscillation"][1]
    assert (tmp_path / "checkerboard.png").stat().st_size > 20_000


@pytest.mark.slow  # three punch scenes with line search: ~60 s on 2 cores
def test_prandtl_punch_quick(tmp_path):
    curves = experiment("prandtl_punch").main(["--quick", "--out", str(tmp_path)])
    assert set(curves) == {("q4", 4.5), ("q1p0", 8.5), ("q1q1", 8.5)}
    assert (tmp_path / "prandtl_punch.png").stat().st_size > 20_000
