"""Sampling optimizers (Latin hypercube + response surface, CMA-ES), the die spline's
B-spline maps and manufacturability rows, and the two-stage design objectives (flash
volume, press capacity, lap, weighted sum), on analytic functions and closed forms.
The real-scene checks are in tests/test_design_spline_scene.py."""

from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxform.config import ConfigError, load_config
from jaxform.design import CmaEs, LhsRsm, optimize
from jaxform.design import objectives as obj
from jaxform.design.parametrize import DieSpline
from jaxform.design.sampling import Quadratic, latin_hypercube
from jaxform.design.spline import Manufacturability, SplineBasis, basis, clamped_knots
from jaxform.gradients import GradientRunError
from jaxform.mesh import rectangle
from jaxform.postprocess import material_beyond


class Analytic:
    """A design problem stand-in: one group 'a' of d variables in [lo, hi]^d, J = f(a);
    designs where ``fails`` is true raise GradientRunError (a run that failed)."""

    def __init__(self, f, d, lo=-2.0, hi=2.0, start=None, fails=None):
        self.f, self.fails = f, fails
        self.start = {"a": np.zeros(d) if start is None else np.asarray(start, float)}
        self.box = (np.full(d, lo), np.full(d, hi))
        self.runs = 0

    def bounds(self):
        return {"a": self.box[0]}, {"a": self.box[1]}

    def value(self, design):
        self.runs += 1
        a = np.asarray(design["a"])
        if self.fails is not None and self.fails(a):
            raise GradientRunError("a step failed")
        return self.f(a), None


def rosenbrock(x):
    return float(np.sum(100.0 * (x[1:] - x[:-1] ** 2) ** 2 + (1.0 - x[:-1]) ** 2))


A3 = np.array([[3.0, 1.0, 0.0], [1.0, 2.0, 0.5], [0.0, 0.5, 1.0]])
X3 = np.array([0.3, -0.5, 1.2])


def quadratic3(x):
    return float(0.5 * (x - X3) @ A3 @ (x - X3) + 2.0)


def test_latin_hypercube_puts_one_sample_in_each_stratum():
    """Reference: the definition; each variable's n values fall one in each [k/n, (k+1)/n)."""
    y = latin_hypercube(16, 3, np.random.default_rng(4))
    for j in range(3):
        assert sorted(np.floor(y[:, j] * 16).astype(int)) == list(range(16))


def test_lhs_rsm_finds_the_minimum_of_a_quadratic():
    """Reference: the minimizer X3 of a full 3-D quadratic inside the box; 8 x 3 = 24
    Latin hypercube runs fit the full quadratic (10 coefficients) exactly, its stationary
    point is the minimizer: found to 1e-6 (measured ~1e-15), verified by run 25; the same
    seed gives the same runs, another seed others."""
    pb = Analytic(quadratic3, 3)
    hist = optimize(pb, LhsRsm(samples_per_variable=8, seed=3))
    assert hist.evaluations == pb.runs == 25 and hist.simulations == list(range(1, 26))
    assert "full quadratic" in hist.stop_reason
    assert np.max(np.abs(hist.designs[-1]["a"] - X3)) <= 1e-6
    assert hist.objective[-1] - 2.0 <= 1e-12 and hist.best == 24
    again = optimize(Analytic(quadratic3, 3), LhsRsm(seed=3))
    assert np.array_equal(np.array(again.objective), np.array(hist.objective))
    other = optimize(Analytic(quadratic3, 3), LhsRsm(seed=4))
    assert not np.array_equal(other.designs[0]["a"], hist.designs[0]["a"])


def test_lhs_rsm_diagonal_surface_and_bounded_minimum():
    """Too few runs for the full quadratic in 4 variables (2 x 4 = 8 < 15 coefficients):
    the diagonal surface, exact for a separable quadratic whose minimizer (1.5, -3, 0.2,
    2.5) lies partly outside [-2, 2]^4: the bounded minimum is its projection (1.5, -2,
    0.2, 2), found to 1e-6 by the bounded search; two rounds, two verification runs."""
    c = np.array([1.5, -3.0, 0.2, 2.5])
    w = np.array([1.0, 2.0, 0.5, 3.0])
    pb = Analytic(lambda x: float(np.sum(w * (x - c) ** 2)), 4)
    hist = optimize(pb, LhsRsm(samples_per_variable=2, rounds=2, seed=1))
    assert hist.evaluations == 10 and "diagonal" in hist.stop_reason
    np.testing.assert_allclose(hist.designs[-1]["a"], np.clip(c, -2, 2), atol=1e-6)


def test_lhs_rsm_leaves_failed_runs_out_of_the_fit():
    """Runs where a_0 > 1 fail: they count as runs (NaN objective, rejected) and the
    surface is fitted to the rest, still exact for the quadratic: minimum X3 to 1e-6."""
    pb = Analytic(quadratic3, 3, fails=lambda a: a[0] > 1.0)
    hist = optimize(pb, LhsRsm(samples_per_variable=8, seed=3))
    assert hist.rejected > 0 and np.isnan(hist.objective).sum() == hist.rejected
    assert np.max(np.abs(hist.designs[hist.best]["a"] - X3)) <= 1e-6


def test_quadratic_minimum_of_an_indefinite_surface_lies_on_the_box():
    """q(s) = -s_0^2 + s_1^2 - 0.5 s_0 on [-1, 1]^2: the minimum is at s = (1, 0) (q = -1.5;
    the other edge s_0 = -1 gives -0.5)."""
    q = Quadratic(0.0, np.array([-0.5, 0.0]), np.diag([-2.0, 2.0]))
    s = q.minimum(np.array([[0.0, 0.5], [-0.5, -0.5], [0.9, 0.9]]))
    np.testing.assert_allclose(s, [1.0, 0.0], atol=1e-8)


@pytest.mark.parametrize("d, budget", [(2, 1000), (3, 1600), (4, 2600)])
def test_cmaes_reaches_rosenbrock_minimum(d, budget):
    """Reference: Rosenbrock's minimum 0 at (1, ..., 1), in [-2, 2]^d from 0 with the
    default population; 1e-6 reached within the budget (measured for seed 0 at 482,
    787, 1270 runs) and the design within 1e-3 of (1, ..., 1)."""
    pb = Analytic(rosenbrock, d)
    hist = optimize(pb, CmaEs(max_simulations=budget, seed=0))
    best = hist.best_so_far()
    assert best[-1] <= 1e-6, best[-1]
    assert np.max(np.abs(hist.designs[hist.best]["a"] - 1.0)) <= 1e-3


def test_cmaes_is_reproducible_and_stays_in_the_box():
    """The same seed gives the same runs, another seed others; the quadratic's minimizer
    (3, 3) lies outside [-2, 2]^2, CMA-ES ends at the box's corner (2, 2) to 1e-6 and
    never runs a design outside the box."""

    def f(x):
        return float(np.sum((x - 3.0) ** 2))

    runs = [optimize(Analytic(f, 2), CmaEs(max_simulations=600, seed=s)) for s in (5, 5, 6)]
    assert np.array_equal(np.array(runs[0].objective), np.array(runs[1].objective))
    assert not np.array_equal(np.array(runs[0].objective), np.array(runs[2].objective))
    h = runs[0]
    np.testing.assert_allclose(h.designs[h.best]["a"], [2.0, 2.0], atol=1e-6)
    assert all(np.all(np.abs(x["a"]) <= 2.0) for x in h.designs)
    assert h.simulations[-1] <= 600


# ----------------------------------------------------------------------------------
# the spline


def test_bspline_reproduces_cubics_and_its_derivative_maps_are_exact():
    """Reference: a clamped cubic B-spline space holds every cubic polynomial, its basis
    sums to 1; z = a r^3 + b r^2 + c r + d fitted at 30 radii is reproduced to 1e-12, D1
    gives coefficients of z' whose spline is z' (to 1e-10), and D2's coefficients are z''
    at the knots (6 a r + 2 b, z'' being linear) to 1e-10."""
    r = np.linspace(1.0, 4.0, 30)
    sp = SplineBasis(1.0, 4.0, 7, r)
    np.testing.assert_allclose(sp.heights().sum(axis=1), 1.0, atol=1e-14)
    a, b, c, d = 0.3, -0.7, 0.2, 5.0
    c_fit = sp.fit(a * r**3 + b * r**2 + c * r + d)
    np.testing.assert_allclose(sp.heights() @ c_fit, a * r**3 + b * r**2 + c * r + d, atol=1e-12)
    t = clamped_knots(1.0, 4.0, 7)
    z1 = basis(t[1:-1], 2, r) @ (sp.slope() @ c_fit)
    np.testing.assert_allclose(z1, 3 * a * r**2 + 2 * b * r + c, atol=1e-10)
    knots = np.unique(t)
    np.testing.assert_allclose(sp.second() @ c_fit, 6 * a * knots + 2 * b, atol=1e-10)


def _spline_group(draft=10.0, radius=2.0):
    r = np.linspace(0.0, 5.0, 11)
    sp = SplineBasis(0.0, 5.0, 6, r)
    c0 = sp.fit(np.full(11, 5.0), {0: 5.0, 5: 5.0})
    return DieSpline(sp, np.arange(11), c0, np.arange(1, 5), Manufacturability(draft, radius))


def test_spline_constraint_rows_report_and_penalty():
    """Reference: a straight ramp z = 5 + s r has every slope coefficient s and z'' = 0:
    the reported draft is atan(1/s) (deg) both from the coefficients and sampled, the
    fillet radius infinite; a slope over cot(10 deg) = 5.67 is penalized as weight x the
    sum of (|s| / 5.67 - 1)^2 over the 5 slope rows; the penalty's gradient matches
    central differences to 1e-7 at a design that violates both constraints."""
    g = _spline_group()
    s = 7.0
    greville = np.array([0, 5 / 9, 5 / 3, 10 / 3, 40 / 9, 5.0])  # knot averages: linear exact
    c_ramp = 5.0 + s * greville
    g = DieSpline(g.spline, g.points, c_ramp, np.arange(6), g.limits)
    u = np.zeros(6)
    np.testing.assert_allclose(g.spline.slope() @ c_ramp, s, rtol=1e-12)
    rows = {row["constraint"]: row for row in g.report(u)}
    assert rows["draft_deg"]["value"] == pytest.approx(np.degrees(np.arctan(1 / s)), rel=1e-10)
    assert rows["draft_sampled_deg"]["value"] == pytest.approx(np.degrees(np.arctan(1 / s)))
    assert rows["draft_deg"]["margin"] < 0 and rows["fillet_radius_mm"]["value"] > 1e9
    cot = 1 / np.tan(np.radians(10.0))
    assert float(g.penalty(u)) == pytest.approx(10.0 * 5 * (s / cot - 1) ** 2, rel=1e-10)
    du = np.random.default_rng(2).standard_normal(6)
    u1 = 0.3 * du
    grad = jax.grad(lambda v: g.penalty(v))(jnp.asarray(u1))
    h = 1e-6
    fd = (float(g.penalty(u1 + h * du)) - float(g.penalty(u1 - h * du))) / (2 * h)
    assert float(grad @ du) == pytest.approx(fd, rel=1e-7)


def test_spline_of_a_flat_die_keeps_it_and_is_feasible():
    """A flat roof with pinned ends: u = 0 gives the roof (heights 5 to 1e-12), no
    penalty; the controls move the points (heights = B c, the end points stay)."""
    g = _spline_group()
    np.testing.assert_allclose(np.asarray(g.heights(jnp.zeros(4))), 5.0, atol=1e-12)
    assert float(g.penalty(jnp.zeros(4))) == 0.0
    z = np.asarray(g.heights(jnp.asarray([0.1, -0.2, 0.0, 0.3])))
    assert z[0] == pytest.approx(5.0) and z[-1] == pytest.approx(5.0)
    assert np.ptp(z) > 0.05


# ----------------------------------------------------------------------------------
# objectives


def _rect_mesh(nr=4, nz=3, w=5.0, h=2.0):
    return rectangle(w, h, nr, nz)


def test_flash_volume_is_the_clipped_measure():
    """Reference: a rectangle [0, 5] x [0, 2] beyond r_f = 3.3 has the volume of
    revolution pi (5^2 - 3.3^2) 2 (two halves: x 2), and the plane area (5 - 3.3) 2; on
    a distorted mesh it equals jaxform.postprocess.material_beyond (Sutherland-Hodgman
    clipping) to 1e-12; its gradient in the positions matches central differences to
    1e-7 (a few nodes on the line r_f: one-sided limits agree, the measure being C1)."""
    mesh = _rect_mesh()
    pos = jnp.asarray(mesh.coords)
    elements = np.asarray(mesh.elements)
    fv = obj.FlashVolume(elements, 3.3, True, halves=2.0)
    traj = SimpleNamespace(positions=pos)
    assert float(fv(traj, None)) == pytest.approx(2 * np.pi * (25 - 3.3**2) * 2, rel=1e-12)
    area = obj.FlashVolume(elements, 3.3, False, halves=1.0)
    assert float(area(traj, None)) == pytest.approx(1.7 * 2, rel=1e-12)
    rng = np.random.default_rng(0)
    moved = np.asarray(mesh.coords) + 0.15 * rng.standard_normal(mesh.coords.shape)
    scene = SimpleNamespace(model=SimpleNamespace(formulation=SimpleNamespace(axisymmetric=True)),
                            mesh=mesh)  # fmt: skip
    ref = material_beyond(scene, moved, 3.3)
    one = obj.FlashVolume(elements, 3.3, True, halves=1.0)
    assert float(one(SimpleNamespace(positions=jnp.asarray(moved)), None)) == pytest.approx(
        ref, rel=1e-12
    )
    f = jax.jit(lambda p: one(SimpleNamespace(positions=p), None))
    g = jax.grad(f)(jnp.asarray(moved))
    d = rng.standard_normal(moved.shape)
    h = 1e-6
    fd = (float(f(moved + h * d)) - float(f(moved - h * d))) / (2 * h)
    assert float(jnp.vdot(g, d)) == pytest.approx(fd, rel=1e-7)


def test_press_capacity_penalty_and_its_gradient():
    """Reference: weight x ((F_max - C) / C)^2 over the capacity, 0 within it; the
    derivative 2 w (F_max - C) / C^2 on the peak row only."""
    pc = obj.PressCapacity(1000.0, weight=3.0)
    f = jnp.asarray([0.0, 600.0, 1200.0, 900.0])
    assert float(pc(SimpleNamespace(force_N=f), None)) == pytest.approx(3.0 * 0.2**2)
    assert float(pc(SimpleNamespace(force_N=0.5 * f), None)) == 0.0
    g = jax.grad(lambda x: pc(SimpleNamespace(force_N=x), None))(f)
    np.testing.assert_allclose(g, [0, 0, 2 * 3.0 * 200.0 / 1000.0**2, 0], rtol=1e-12)


def test_lap_penalty_measures_the_air_wedges():
    """Reference: the boundary of a square [0, 1]^2 (CCW) has air-side angles of 270 deg
    at its corners (no penalty below 30 deg); pulling one corner's neighbours into a
    wedge of 20 deg gives (1 - 20/30)^2 there; the gradient matches central differences
    to 1e-7."""
    pts = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    idx = np.arange(4)
    lp = obj.LapPenalty(np.roll(idx, 1), idx, np.roll(idx, -1), np.radians(30.0))
    np.testing.assert_allclose(np.degrees(np.asarray(lp.angles(jnp.asarray(pts)))), 270.0)
    # vertex 1 at the tip of a 20 deg air wedge: the boundary (material on its left)
    # comes in along +r and turns right by 160 deg, air-side angle pi + turn
    a = np.radians(20.0)
    wedge = np.array([[-1.0, 0.0], [0.0, 0.0], [-np.cos(a), -np.sin(a)], [-2.0, -3.0]])
    ang = np.degrees(np.asarray(lp.angles(jnp.asarray(wedge))))
    assert ang[1] == pytest.approx(20.0, abs=1e-9)
    val = float(lp(SimpleNamespace(positions=jnp.asarray(wedge)), None))
    expected = sum(max(0.0, 1 - x / 30.0) ** 2 for x in ang)
    assert val == pytest.approx(expected, rel=1e-12) and val >= (1 - 20 / 30) ** 2
    f = jax.jit(lambda p: lp(SimpleNamespace(positions=p), None))
    g = jax.grad(f)(jnp.asarray(wedge))
    d = np.random.default_rng(1).standard_normal(wedge.shape)
    h = 1e-6
    fd = (float(f(wedge + h * d)) - float(f(wedge - h * d))) / (2 * h)
    assert float(jnp.vdot(g, d)) == pytest.approx(fd, rel=1e-7)


def test_weighted_sum_lists_its_terms():
    pc = obj.PressCapacity(1000.0)
    pf = obj.PeakForce()
    ws = obj.WeightedSum(("press_capacity", "peak_force"), (pc, pf), (2.0, 1e-3))
    traj = SimpleNamespace(force_N=jnp.asarray([0.0, 1500.0]))
    vals = {k: float(v) for k, v in ws.values(traj, None).items()}
    assert vals == pytest.approx({"press_capacity": 0.25, "peak_force": 1500.0})
    assert float(ws(traj, None)) == pytest.approx(2 * 0.25 + 1.5)


# ----------------------------------------------------------------------------------
# config


SCENE = "experiments/spline_die_design.toml"


@pytest.mark.parametrize(
    "overrides, message",
    [
        (["design.die_spline_controls=0"], "'die_spline' needs design.die_spline_controls >= 2"),
        (["design.die_draft_deg=95"], "design.die_draft_deg"),
        (["design.optimizer=simplex"], "design.optimizer"),
        (["design.terms=[]"], "design.terms (now []) and as many design.term_weights"),
        (["design.term_weights=[1.0]"], "as many design.term_weights (now [1.0])"),
        (["design.terms=['flash_volume']", "design.term_weights=[1.0]",
          "design.flash_radius_mm=0"], "'flash_volume' needs design.flash_radius_mm > 0"),
        (["design.objective=press_capacity"], "design.press_capacity_N > 0"),
    ],
)  # fmt: skip
def test_design_keys_are_checked_before_anything_compiles(overrides, message):
    """Each bad key is one line naming it (ConfigError, exit 2 in the CLI)."""
    from jaxform.config import typed
    from jaxform.design.requirements import check_gradient_run

    with pytest.raises(ConfigError) as err:
        cfg = typed(load_config(SCENE, overrides))
        check_gradient_run(cfg, cfg.design.variables)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_spline_range_with_a_wall_inside_is_refused():
    """A range that reaches over the container wall (two points at r = 6.5 mm) cannot be
    a height z(r): one line naming the keys."""
    from jaxform.design.problem import build_group
    from jaxform.scenes import build_scene

    sc = build_scene(load_config(SCENE, ["design.die_spline_r1_mm=7"]))
    with pytest.raises(ConfigError, match="design.die_spline_r0_mm, r1_mm = 0, 7 mm"):
        build_group(sc, "die_spline")
