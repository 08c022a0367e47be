"""Rounded die profiles and the die-fill volume (geometry only, no simulation: fast).

References: closed-form circle and rectangle geometry; Pappus volumes of revolution.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxform.config import ConfigError, load_config
from jaxform.design.objectives import cavity_volume as design_cavity
from jaxform.design.objectives import part_cavity_volume
from jaxform.dies import (
    closest_point_gap,
    corner_gap,
    make_die,
    rounded_polyline,
    sample_rounded,
)
from jaxform.postprocess import cavity_volume, filled_volume, material_volume
from jaxform.scenes import build_scene

# a concave die corner (cavity corner): walked +x, then down: right turn
CORNER = np.array([[0.0, 1.0], [1.0, 1.0], [1.0, -1.0]])


def _gap(points, radius, x):
    return jax.vmap(lambda p: closest_point_gap(jnp.asarray(points), radius, p))(jnp.asarray(x))


def test_rounded_corner_is_the_tangent_circle():
    """90 deg corner, R = 0.2: the arc has centre (0.8, 0.8) and radius 0.2; near it
    g = 0.2 - |x - c| (workpiece inside the circle), on the flats g is the distance to the
    line; grad g = n everywhere (jax.grad, 1e-12)."""
    rng = np.random.default_rng(1)
    ang = rng.uniform(0.0, np.pi / 2, 50)
    rad = rng.uniform(0.1, 0.3, 50)
    x = np.column_stack([0.8 + rad * np.cos(ang), 0.8 + rad * np.sin(ang)])
    g, n, _ = (np.asarray(a) for a in _gap(CORNER, 0.2, x))
    assert np.max(np.abs(g - (0.2 - rad))) <= 1e-12
    assert np.max(np.abs(n + np.column_stack([np.cos(ang), np.sin(ang)]))) <= 1e-12
    flat = np.column_stack([rng.uniform(-1.0, 0.7, 20), rng.uniform(0.5, 1.2, 20)])
    assert np.max(np.abs(np.asarray(_gap(CORNER, 0.2, flat)[0]) - (1.0 - flat[:, 1]))) <= 1e-12
    grad = jax.vmap(jax.grad(lambda p: closest_point_gap(jnp.asarray(CORNER), 0.2, p)[0]))(
        jnp.asarray(x)
    )
    assert np.max(np.abs(np.asarray(grad) - n)) <= 1e-12


def test_rounded_profile_is_c1_and_keeps_sampled_fillets():
    """Along the rounded profile the normal turns by at most the sampling angle (no
    jumps).  A polyline that samples a unit circle (22.5 deg steps) becomes, with a
    large corner radius, the concentric circle through the chords' midpoints (radius
    cos 11.25 deg): points on the unit circle between the first and last chord midpoints,
    at vertices or between, have
    g = -(1 - cos 11.25 deg) (1e-12)."""
    th = np.radians(np.arange(0.0, 90.1, 22.5))
    circle = np.column_stack([np.sin(th), np.cos(th)])  # walked clockwise: a convex die
    pts = np.vstack([[-1.0, 1.0], circle, [1.0, -1.0]])
    dense = sample_rounded(pts, 5.0, per_arc=32)
    g, n, _ = (np.asarray(a) for a in _gap(pts, 5.0, dense))
    assert np.max(np.abs(g)) <= 1e-12
    turn = np.degrees(np.arccos(np.clip(np.sum(n[1:] * n[:-1], axis=1), -1.0, 1.0)))
    assert turn.max() <= 22.5 / 32 + 1e-9
    ang = np.radians([15.0, 22.5, 30.0, 45.0, 60.0, 75.0])  # between the end chords' midpoints
    on_circle = np.column_stack([np.sin(ang), np.cos(ang)])
    g = np.asarray(_gap(pts, 5.0, on_circle)[0])
    assert np.max(np.abs(g + (1.0 - np.cos(np.radians(11.25))))) <= 1e-12


# the two-stage disk's finisher (configs/two_stage_disk.toml): a web, a rib cavity, a
# flash land and a gutter, corner radius 0.3 mm
FINISHER = np.array([[0, 2.0], [4.3, 2.0], [4.6, 3.5], [6.1, 3.5], [6.4, 1.4], [7.4, 1.4],
                     [7.4, 2.5], [12.0, 2.5]])  # fmt: skip


def test_the_traced_rounded_polyline_is_the_drawn_one():
    """rounded_polyline (traceable, the design objectives' cavity) gives sample_rounded's
    points (the history's die_fill) to 1e-12 mm."""
    got = np.asarray(rounded_polyline(jnp.asarray(FINISHER), 0.3))
    assert got.shape == sample_rounded(FINISHER, 0.3).shape
    assert np.max(np.abs(got - sample_rounded(FINISHER, 0.3))) <= 1e-12


def test_design_cavity_of_a_rounded_convex_corner_in_closed_form():
    """A top die of (0, 1) -> (2, 1) -> (2, 3) (a convex die corner at (2, 1)) rounded by
    r = 0.5 over the mid-plane, plane strain: the cavity gains the corner less the arc's
    16 chords' fan, 2 + r^2 - 8 r^2 sin(pi/32) mm^2 (1e-12); sharp, 2 mm^2.  On the disk's
    finisher moved 1 mm down, inside r <= 6.4 mm: the volume of the drawn rounded outline
    (1e-9 relative)."""
    r, die = 0.5, jnp.asarray([[0.0, 1.0], [2.0, 1.0], [2.0, 3.0]])
    exact = 2.0 + r * r - 8.0 * r * r * np.sin(np.pi / 32)
    assert abs(float(design_cavity(die, 0.0, False, r)) - exact) <= 1e-12
    assert abs(float(design_cavity(die, 0.0, False)) - 2.0) <= 1e-12
    drawn = part_cavity_volume(jnp.asarray(sample_rounded(FINISHER, 0.3)), 1.0, 6.4, True)
    traced = part_cavity_volume(jnp.asarray(FINISHER), 1.0, 6.4, True, 0.3)
    assert abs(float(traced) / float(drawn) - 1.0) <= 1e-9


def test_design_cavity_gradient_through_the_rounding():
    """d(cavity)/d(points, corner radius) of a profile with a vertex that does not turn and
    one that turns by 1e-5 rad (a sampled spline die) against central differences
    (h = 1e-6 mm for the points, 1e-4 mm for the radius; 1e-6 relative); finite
    everywhere."""
    pts = np.array([[0.0, 3.3], [0.5, 3.3], [1.0, 3.3], [1.5, 3.300005], [4.0, 3.3],
                    [5.0, 4.3], [12.0, 4.3]])  # fmt: skip

    def cav(p, rad):
        return part_cavity_volume(p, 0.2, 6.0, True, rad)

    g_p, g_r = jax.grad(cav, argnums=(0, 1))(jnp.asarray(pts), 0.5)
    assert np.all(np.isfinite(np.asarray(g_p)))
    du = np.random.default_rng(4).standard_normal(pts.shape)
    h = 1e-6
    fd = (
        float(cav(jnp.asarray(pts + h * du), 0.5)) - float(cav(jnp.asarray(pts - h * du), 0.5))
    ) / (2 * h)
    assert abs(fd - float(np.sum(np.asarray(g_p) * du))) <= 1e-6 * abs(fd)
    h = 1e-4  # the radius moves the cavity by ~0.1 mm^3 per mm: a larger step than round-off
    fd_r = (float(cav(jnp.asarray(pts), 0.5 + h)) - float(cav(jnp.asarray(pts), 0.5 - h))) / (2 * h)
    assert abs(fd_r - float(g_r)) <= 1e-6 * abs(fd_r)


@pytest.mark.parametrize("seed", range(6))
def test_intersection_where_material_runs_along_a_die_wall_and_leaves_it(seed):
    """The material's boundary runs along a slanted die wall between s0 and s1 of it
    (vertices put on the wall in floating point, as contact puts nodes) and leaves it
    there outwards; elsewhere the material reaches past the wall, so it holds the whole
    cavity: intersection = cavity (plane strain, 1e-12 relative; axisymmetric likewise).
    Where the boundaries part at a vertex a crossing test misses by round-off, the wall
    was counted whole or not at all (the two-stage disk's designed finisher read a fill of
    0.907 for 0.990)."""
    from jaxform.geometry import polygon_measure
    from jaxform.postprocess import _clipped_boundary_integral

    rng = np.random.default_rng(seed)
    foot, top = np.array([2.0, 0.0]), np.array([2.0 - rng.uniform(0.2, 0.8), 2.0])
    cav = np.array([[0.0, 0.0], foot, top, [0.0, 2.0]])  # counter-clockwise
    s0, s1 = np.sort(rng.uniform(0.1, 0.9, 2))
    p0, p1 = foot + s0 * (top - foot), foot + s1 * (top - foot)
    mat = np.array([[0.0, 0.0], [3.0, 0.0], [3.0, p0[1]], p0, p1, [3.0, p1[1]], [3.0, 2.0],
                    [0.0, 2.0]])  # fmt: skip
    for axi in (False, True):
        tol = 1e-9 * 3.0
        m0, m1, c0, c1 = mat, np.roll(mat, -1, axis=0), cav, np.roll(cav, -1, axis=0)
        got = _clipped_boundary_integral(m0, m1, c0, c1, True, tol, axi)
        got += _clipped_boundary_integral(c0, c1, m0, m1, False, tol, axi)
        got = 2.0 * np.pi * got if axi else got
        want = float(polygon_measure(cav, axi))
        assert abs(got / want - 1.0) <= 1e-12, (axi, got, want)


def test_a_zero_corner_radius_is_rejected():
    with pytest.raises(ValueError, match="corner radius"):
        make_die(CORNER, [0.0, 1.0], [0.0, 1.0], corner_radius=0.0)
    with pytest.raises(ValueError, match="die.corner_radius_mm"):
        load_config(
            {
                "billet": {"diameter_mm": 4.0, "height_mm": 2.0},
                "time": {"dt_s": 1.0},
                "die": {"speed_mm_s": 0.1, "reduction": 0.1, "corner_radius_mm": 0.0},
            }
        )


def _closed_die_scene(profile, nr=4, nz=3, **die):
    """A closed die of ``profile`` (and ``die`` keys) over the billet r < 2, z < 1 (only
    the geometry is used)."""
    die = {"speed_mm_s": 0.1, "reduction": 0.1, "closed": True, "profile_mm": profile, **die}
    return build_scene(
        load_config(
            {
                "billet": {"diameter_mm": 4.0, "height_mm": 2.0},
                "mesh": {"nr": nr, "nz": nz},
                "die": die,
                "time": {"dt_s": 1.0},
            }
        )
    )


def _cylinder_cavity_scene(nr=4, nz=3):
    """Closed flat die at z = 2 over r in [0, 3] (cavity: cylinder r < 3, z < 2), billet
    r < 2, z < 1 (only the geometry is used)."""
    return _closed_die_scene([[0.0, 2.0], [3.0, 2.0], [3.0, 0.0]], nr, nz)


@pytest.mark.parametrize(
    "width, height, expected",
    [
        (2.0, 1.0, np.pi * 4.0 * 1.0),  # inside: all of it
        (2.0, 2.5, np.pi * 4.0 * 2.0),  # taller: cut at the die face, z = 2
        (3.5, 2.5, None),  # wider and taller: fills the cylinder up to the rounded corner
    ],
)
def test_filled_volume_is_the_material_inside_the_cavity(width, height, expected):
    """Billet section scaled to width x height: the filled volume is the Pappus volume of
    its intersection with the cavity (1e-12 relative); a rectangle covering the whole
    cavity fills it exactly."""
    sc = _cylinder_cavity_scene()
    c0 = np.asarray(sc.mesh.coords)
    pos = c0 * np.array([width / 2.0, height / 1.0])
    v = filled_volume(sc, pos, 0.0)
    if expected is None:
        expected = cavity_volume(sc, 0.0)
    else:
        assert abs(material_volume(sc, pos) - np.pi * width**2 * height) <= 1e-9 * v
    assert abs(v / expected - 1.0) <= 1e-12, (v, expected)


def _on_the_rounded_corner():
    """The cylinder cavity's scene (die corner radius 0.5 mm at (3, 2)) and a section that
    fills it with a 4 x 3 mesh: the rectangle [0, 3] x [0, 2], its corner node moved onto
    the corner's arc at 45 degrees, so that the two edges beside it are chords of the
    rounded corner (ends on the die, the arc outside the material)."""
    sc = _cylinder_cavity_scene()
    pos = np.asarray(sc.mesh.coords) * np.array([1.5, 2.0])
    corner = np.argmin(np.linalg.norm(pos - np.array([3.0, 2.0]), axis=1))
    pos[corner] = np.array([2.5, 1.5]) + 0.5 / np.sqrt(2.0)
    return sc, pos


def test_a_section_whose_nodes_lie_on_the_die_fills_its_rounded_corner():
    """Every boundary node of the section lies on the die (the rounded corner's arc
    between two of them): the history's fill is 1 (1e-12) and the design's traced
    UnfilledCavity 0 (1e-12): the chords across the arc are the mesh's, not air
    (:mod:`jaxform.fill`).  Without the conforming the two chords read the slivers
    between them and the arc as unfilled (checked here: > 1e-4 of the cavity)."""
    from jaxform.design.objectives import UnfilledCavity
    from jaxform.geometry import polygon_measure
    from jaxform.mesh import boundary_edges

    sc, pos = _on_the_rounded_corner()
    cav = cavity_volume(sc, 0.0)
    assert abs(filled_volume(sc, pos, 0.0) / cav - 1.0) <= 1e-12
    raw = float(np.sum(polygon_measure(pos[np.asarray(sc.mesh.elements)], True)))
    assert 1.0 - raw / cav > 1e-4  # the slivers a chord leaves
    obj = UnfilledCavity(np.asarray(sc.mesh.elements), True)
    assert abs(float(obj(_trajectory(jnp.asarray(pos)), sc.inputs))) <= 1e-12
    # sliding a node along the die's flat face changes nothing: zero derivative along it
    edges = boundary_edges(np.asarray(sc.mesh.elements))
    top = [n for n in np.unique(edges) if abs(pos[n, 1] - 2.0) < 1e-12 and 0.1 < pos[n, 0] < 2.4]
    grad = jax.grad(lambda p: obj(_trajectory(p), sc.inputs))(jnp.asarray(pos))
    assert len(top) == 3 and np.all(np.abs(np.asarray(grad)[top, 0]) <= 1e-12)


def _trajectory(positions):
    """The end of a run as the design objectives read it: positions, time."""
    from types import SimpleNamespace

    return SimpleNamespace(positions=positions, time_s=jnp.zeros(1))


def test_a_section_bridging_a_groove_leaves_it_unfilled():
    """A die with a groove 0.5 mm deep (r 0.85 .. 1.35 mm) over a flat section whose top
    nodes at r = 0.75 and 1.5 mm lie on the die on either side of it: the die's path
    between them is 2.1 times the edge, so the edge is no chord of the die (it bridges
    the groove) and the groove reads unfilled.  Reference: the section's own Pappus
    volume (it lies under the die) over the cavity's, 1e-6 (the die's corner radius of
    1e-3 mm at the section's top corner)."""
    groove = [[0.0, 2.0], [0.85, 2.0], [0.95, 2.5], [1.25, 2.5], [1.35, 2.0], [3.0, 2.0],
              [3.0, 0.0]]  # fmt: skip
    sc = _closed_die_scene(groove, corner_radius_mm=1e-3)
    pos = np.asarray(sc.mesh.coords) * np.array([1.5, 2.0])
    expected = np.pi * 3.0**2 * 2.0 / cavity_volume(sc, 0.0)
    assert expected < 0.99  # the groove is a visible part of the cavity
    assert filled_volume(sc, pos, 0.0) / cavity_volume(sc, 0.0) == pytest.approx(expected, rel=1e-6)


def test_part_fill_and_flash_volume_split_at_the_part_radius():
    """A flat closed die at z = 2 over r in [0, 3] with the part ending at r = 1.5 (the
    rest a flash land).  Reference, by hand (Pappus, whole workpiece = both halves):
    a billet section r < 2.5, z < 2 fills the part cylinder r < 1.5, z < 2 exactly
    (fill 1) and has pi (2.5^2 - 1.5^2) x 2 x 2 = 16 pi mm^3 beyond r = 1.5; one of
    r < 1, z < 2 fills (1/1.5)^2 of the part and has no flash.  1e-12 relative."""
    from jaxform.postprocess import extra_history

    sc = _closed_die_scene([[0.0, 2.0], [3.0, 2.0], [3.0, 0.0]], nr=5, part_radius_mm=1.5,
                           corner_radius_mm=1e-3)  # fmt: skip
    c0 = np.asarray(sc.mesh.coords)
    lay = sc.model.layout
    rows = []
    for width in (2.5, 1.0):  # section half-widths, 2 mm high (to the die face)
        x = np.zeros(lay.n_dofs)
        lay.nodal(x)[:, :2] = c0 * np.array([width / 2.0, 2.0]) - c0
        rows.append(x)
    cols = extra_history(sc, np.array(rows), np.zeros(2))
    np.testing.assert_allclose(cols["die_fill"], [1.0, (1.0 / 1.5) ** 2], rtol=1e-12)
    np.testing.assert_allclose(cols["flash_volume_mm3"][0], 16.0 * np.pi, rtol=1e-12)
    assert cols["flash_volume_mm3"][1] == 0.0
    assert np.all(cols["die_overlap_mm"] == 0.0)  # the die face lies on the material
    # the fill never reads more than the material on the part's side of its radius: a
    # boundary integral that counts a stretch twice (as one did at the end of a generated
    # die's stroke: 1.089) is capped there (here: the narrow section, (1/1.5)^2)
    import jaxform.postprocess as post

    real = post._clipped_boundary_integral
    post._clipped_boundary_integral = lambda *a: 2.0 * real(*a)
    try:
        narrow = extra_history(sc, np.array(rows[1:]), np.zeros(1))["die_fill"][0]
    finally:
        post._clipped_boundary_integral = real
    assert narrow == pytest.approx((1.0 / 1.5) ** 2, rel=1e-12)
    with pytest.raises(ConfigError, match="die.part_radius_mm = 1.5: needs die.closed"):
        die = {"speed_mm_s": 0.1, "reduction": 0.1, "part_radius_mm": 1.5}
        load_config({"billet": {"diameter_mm": 4.0, "height_mm": 2.0}, "time": {"dt_s": 1.0},
                     "die": die})  # fmt: skip


@pytest.mark.parametrize("radius, half_width", [(1.0, 0.3), (5.0, 0.5), (0.5, 0.49)])
def test_die_overlap_is_the_sagitta_of_a_convex_corner_between_two_nodes(radius, half_width):
    """Reference, closed form: a convex die arc of radius R resting on the two top nodes of
    a facet of length 2a (both nodes on the arc) reaches into the material by the sagitta
    R - sqrt(R^2 - a^2) at the facet's middle.  Sampled with the apex among the points:
    1e-12 mm.  The same arc lifted clear of the facet overlaps by 0."""
    from jaxform.mesh import boundary_edges
    from jaxform.postprocess import overlap_depth

    a = half_width
    pos = np.array([[-a, -2.0], [a, -2.0], [a, 0.0], [-a, 0.0]])  # one quad, top facet z = 0
    edges = boundary_edges(np.array([[0, 1, 2, 3]]))
    centre = np.sqrt(radius**2 - a**2)
    ang = -0.5 * np.pi + np.linspace(-1.0, 1.0, 2001) * np.pi / 2
    circle = np.column_stack([radius * np.cos(ang), centre + radius * np.sin(ang)])
    expected = radius - centre
    assert abs(overlap_depth(circle, pos, edges) - expected) <= 1e-12
    assert overlap_depth(circle + np.array([0.0, expected + 1e-6]), pos, edges) == 0.0


def test_a_facet_lets_go_of_an_arc_gradually_at_its_node():
    """A facet lying on a flat die face, its node a crossing the tangent point E where the
    face runs into a convex edge arc (R = 0.3): the arc's deepest point is E, at the
    facet's depth (raw gap 0).  Away from the nodes the corner gap is that raw gap (0 to
    1e-12); within END_SHARE of node a it rises linearly to the facet length, which is
    the gap of a disengaged facet, so nothing jumps as E crosses the node (the jump made
    Newton cycle: docs/remeshing.md).  Reference: the closed form
    g = L (END_SHARE - xi) / END_SHARE for xi = |E - x_a| / L < END_SHARE, to 1e-12."""
    from jaxform.dies import END_SHARE

    pts = jnp.asarray([[0.0, 1.0], [2.0, 1.0], [2.0, 3.0]])  # flat face, then up: convex
    radius, length = 0.3, 0.25
    e_r = 2.0 - radius  # the tangent point on the flat face

    def gap(s):  # facet from x_a = E + s (towards the edge) back along the face
        xa = jnp.asarray([e_r + s, 1.0])
        xb = jnp.asarray([e_r + s - length, 1.0])
        return corner_gap(pts, radius, xa, xb)

    for xi in (0.5, 0.3, END_SHARE + 1e-3):
        g, engaged = gap(xi * length)
        assert bool(engaged) and abs(float(g)) <= 1e-12, (xi, g)
    for xi in (0.075, 0.05, 0.02, 1e-9):
        g, engaged = gap(xi * length)
        want = length * (END_SHARE - xi) / END_SHARE
        assert bool(engaged) and abs(float(g) - want) <= 1e-12, (xi, g, want)
    g, engaged = gap(-0.01 * length)  # E beyond node a: the facet has let go
    assert not bool(engaged) and float(g) == pytest.approx(length, abs=1e-12)


_ARC_END_DIE = np.array([[0.0, 1.0], [2.0, 1.0], [2.0, 3.0]])  # flat, then up: convex
_ARC_END_RADIUS = 0.3


class _ArcEndDie:
    """The die of the facet tests below: a flat face whose convex corner arc ends tangent
    to it (the die pytree's two gap methods, at rest)."""

    def facet_gap(self, xa, xb, t):
        return corner_gap(_ARC_END_DIE, _ARC_END_RADIUS, xa, xb)

    def gap(self, x, t):
        return closest_point_gap(_ARC_END_DIE, _ARC_END_RADIUS, x)


def test_a_facet_on_a_flat_face_at_an_arc_end_with_no_force_is_open():
    """The singular tie of docs/remeshing.md: a new mesh puts a facet on the flat face where
    a convex arc ends tangent to it; the arc's deepest point is the arc end, on the facet's
    line (raw gap 0 to round-off), and the carried multiplier is 0.  The facet condition
    C = mu - max(0, mu - c (g + FACET_OPEN_REACH_MM)) must then be the open one, C = mu
    (dC/dmu = 1, dC/dx = 0: the row ties with nothing), for gaps within round-off of 0 on
    either side.  Once the arc reaches 1e-6 mm into the facet the condition is the active
    one, C = c (g + e) (dC/dmu = 0, dC/dz = c/2 at each node for an arc touching
    mid-facet).  Reference: the two branches' derivatives, exact (to 1e-9)."""
    from jaxform.contact import FACET_OPEN_REACH_MM, facet_terms

    pts, radius, Die = _ARC_END_DIE, _ARC_END_RADIUS, _ArcEndDie
    length, c = 0.25, 1e4
    e_r = 2.0 - radius  # the arc's end, tangent to the flat face

    def condition_row(dz):  # the facet's two nodes dz below the face, the arc end mid-facet
        v = jnp.asarray([e_r + 0.5 * length, 1.0 - dz, e_r - 0.5 * length, 1.0 - dz, 0.0])
        g, _ = corner_gap(pts, radius, v[:2], v[2:4])
        return float(g), np.asarray(jax.jacfwd(lambda w: facet_terms(Die(), w, 0.0, c)[4])(v))

    for dz in (0.0, 1e-15, -1e-15, 1e-13):
        g, row = condition_row(dz)
        assert abs(g) <= 1e-12 < FACET_OPEN_REACH_MM, (dz, g)
        np.testing.assert_array_equal(row, [0.0, 0.0, 0.0, 0.0, 1.0], err_msg=f"dz {dz}")
    g, row = condition_row(-1e-6)  # the arc 1e-6 mm into the facet: active
    assert g == pytest.approx(-1e-6, abs=1e-12)
    # the arc touches mid-facet: its reach is shared evenly by the two nodes' heights
    assert row[4] == 0.0 and row[1] == pytest.approx(-0.5 * c, rel=1e-9)
    assert row[3] == pytest.approx(-0.5 * c, rel=1e-9)


def test_a_facet_open_by_its_nodes_depth_adds_no_tie():
    """``facet_terms(..., by_node_depth=True)``, the law of a step retried after a singular
    Jacobian (docs/benchmarks.md: the asymmetric closed die's Newton iterate with both
    nodes 0.2 - 0.4 um inside the anvil's face and the arc end between them).  The facet of
    the test above with its nodes 1e-6 mm inside the face, the arc reaching as far into it:
    by the default law the row is the active one, a combination of the nodes' own rows
    (c/2 each: a singular Jacobian with them); opened by the nodes' depth it is C = mu.  A
    facet across the corner that the arc reaches into beyond its nodes' depth stays
    active: C = c (g + e + depth), its row c dg/dx plus c d(-g_b)/dx of the deeper node b
    (c at z_b), with its nodes on the faces (depth 0: the default law's row) or a 0.5e-4
    and b 1e-4 mm inside them.  Reference: the branches' derivatives, exact (to 1e-9)."""
    from jaxform.contact import facet_terms

    pts, radius, Die = _ARC_END_DIE, _ARC_END_RADIUS, _ArcEndDie
    length, c = 0.25, 1e4
    e_r = 2.0 - radius

    def row(v, by_depth):
        v = jnp.asarray(v)
        return np.asarray(jax.jacfwd(lambda w: facet_terms(Die(), w, 0.0, c, by_depth)[4])(v))

    inside = [e_r + 0.5 * length, 1.0 + 1e-6, e_r - 0.5 * length, 1.0 + 1e-6, 0.0]
    tied = row(inside, False)
    assert tied[4] == 0.0 and tied[1] == pytest.approx(-0.5 * c, rel=1e-9)
    np.testing.assert_array_equal(row(inside, True), [0.0, 0.0, 0.0, 0.0, 1.0])
    for depth, extra in ((0.0, [0.0, 0.0, 0.0, 0.0]), (1e-4, [0.0, 0.0, 0.0, c])):
        v = [2.0 - 0.5 * depth, 1.5, 1.5, 1.0 + depth, 0.0]
        g, _ = corner_gap(pts, radius, jnp.asarray(v[:2]), jnp.asarray(v[2:4]))
        assert float(g) < -0.2
        gb = float(Die().gap(jnp.asarray(v[2:4]), 0.0)[0])
        assert gb == pytest.approx(-depth, abs=1e-15)
        dg = np.asarray(jax.grad(lambda w: corner_gap(pts, radius, w[:2], w[2:])[0])(
            jnp.asarray(v[:4])))  # fmt: skip
        opened = row(v, True)
        assert opened[4] == 0.0
        np.testing.assert_allclose(opened[:4], c * dg + np.asarray(extra), rtol=1e-9)
        if depth == 0.0:
            np.testing.assert_array_equal(opened, row(v, False))
