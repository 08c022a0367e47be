"""Rezoning: the element quality measure, quality-driven smoothing, state transfer.

References: corner quality of a square, rectangle and rhombus in closed form; exact
area / Pappus volume of a polygon whose boundary nodes slide along straight sides;
exactness of bilinear interpolation for fields linear in space (isoparametric quads
reproduce linear functions).
"""

import numpy as np
import pytest

from jaxform import element as el
from jaxform.geometry import polygon_measure
from jaxform.mesh import rectangle
from jaxform.rezone import corner_qualities, min_quality, restore_volume, smooth
from jaxform.transfer import Transfer


def _distorted_grid(nr=6, nz=5, seed=3):
    m = rectangle(3.0, 2.0, nr, nz)
    rng = np.random.default_rng(seed)
    pos = np.asarray(m.coords).copy()
    ids = np.arange(len(pos)).reshape(nz + 1, nr + 1)
    inner = ids[1:-1, 1:-1].ravel()
    pos[inner] += rng.uniform(-0.18, 0.18, (len(inner), 2))
    return m, pos, ids


def test_smoothing_raises_the_quality_and_keeps_the_volume():
    """Randomly distorted 6x5 grid of a 3 x 2 rectangle (no die in reach): smoothing raises
    the worst corner quality above 0.8 (from < 0.5), keeps every boundary node on its side
    and the area and the volume of revolution to 1e-12."""
    m, pos, ids = _distorted_grid()
    elements = np.asarray(m.elements)
    before = min_quality(pos, elements)
    assert before < 0.5

    def far(p):  # no die in reach
        return np.full(len(p), 10.0), np.tile([0.0, -1.0], (len(p), 1))

    for axi in (True, False):
        new = smooth(pos, 6, 5, far, axisymmetric=axi)
        assert min_quality(new, elements) > 0.8
        for side, col, val in (
            (ids[0], 1, 0.0),
            (ids[-1], 1, 2.0),
            (ids[:, 0], 0, 0.0),
            (ids[:, -1], 0, 3.0),
        ):
            assert np.max(np.abs(new[side, col] - val)) <= 1e-12
        v0 = polygon_measure(pos[elements], axi).sum()
        v1 = polygon_measure(new[elements], axi).sum()
        assert abs(v1 / v0 - 1.0) <= 1e-12


def test_rezoning_restores_the_volume_under_a_curved_die():
    """A 6x5 grid of a section 3 mm wide whose top lies on a circular die (radius 3 mm,
    centre (1.5, 5) mm), its top nodes bunched unevenly along the die: smoothing slides
    them along the die, which moves the chords across the arc and changes the volume
    (measured ~1e-4); the restoration brings it back to 1e-12 by a common normal offset
    of the free nodes (the outer side), leaves the pinned nodes (axis, mid-plane) and the
    nodes on the die where they are, and keeps the quality the smoothing reached (1e-3)."""
    nr, nz = 6, 5
    m, pos, ids = _distorted_grid(nr, nz, seed=5)
    centre, radius = np.array([1.5, 5.0]), 3.0
    s_top = np.linspace(0.0, 1.0, nr + 1)
    r_top = 3.0 * (s_top + 0.07 * np.sin(2.0 * np.pi * s_top))
    pos[ids[-1], 0] = r_top
    top_z = centre[1] - np.sqrt(radius**2 - (pos[:, 0] - centre[0]) ** 2)
    pos[:, 1] *= top_z / 2.0  # the section reaches up to the die
    elements = np.asarray(m.elements)

    def circle_die(p):  # signed distance to the die, and the normal into the material
        d = p - centre
        dist = np.linalg.norm(d, axis=1)
        return dist - radius, d / dist[:, None]

    assert np.max(np.abs(circle_die(pos[ids[-1]])[0])) <= 1e-12
    pinned = set(np.concatenate([ids[0], ids[:, 0]]).tolist())  # mid-plane, axis
    for axi in (True, False):
        v0 = polygon_measure(pos[elements], axi).sum()
        new = smooth(pos, nr, nz, circle_die, axisymmetric=axi, pinned=pinned)
        v_smooth = polygon_measure(new[elements], axi).sum()
        assert abs(v_smooth / v0 - 1.0) > 1e-6  # the smoothing did change the volume
        out = restore_volume(new, nr, nz, v0, circle_die, axi, pinned)
        assert abs(polygon_measure(out[elements], axi).sum() / v0 - 1.0) <= 1e-12
        on_die = np.nonzero(np.abs(circle_die(new)[0]) <= 1e-6)[0]
        fixed = np.array(sorted(pinned | set(on_die.tolist())))
        assert np.array_equal(out[fixed], new[fixed])
        assert min_quality(out, elements) >= min_quality(new, elements) - 1e-3


def test_transfer_reproduces_linear_fields():
    """Gauss-point field f = 2 + 3 r - z on a distorted grid, carried to the Gauss points
    and nodes of the smoothed grid: exact (1e-12) everywhere, boundary included (patch
    recovery is exact for linear fields and its limiter leaves them alone)."""
    m, pos, ids = _distorted_grid()
    elements = np.asarray(m.elements)
    new = smooth(pos, 6, 5, lambda p: (np.full(len(p), 10.0), np.tile([0.0, -1.0], (len(p), 1))))

    def field(p):
        return 2.0 + 3.0 * p[..., 0] - p[..., 1]

    gp_old = np.einsum("ga,eai->egi", el.N_GP, pos[elements])
    gp_new = np.einsum("ga,eai->egi", el.N_GP, new[elements])
    move = Transfer(pos, elements, new, elements)
    assert np.max(np.abs(move.gauss(field(gp_old)) - field(gp_new))) <= 1e-12
    assert np.max(np.abs(move.nodal(field(pos)) - field(new))) <= 1e-12
    # a tensor field (per component) likewise
    tensor = field(gp_old)[..., None, None] * np.arange(1.0, 5.0).reshape(2, 2)
    want = field(gp_new)[..., None, None] * np.arange(1.0, 5.0).reshape(2, 2)
    assert np.max(np.abs(move.gauss(tensor) - want)) <= 1e-11


def test_corner_quality_values():
    """Square 1, 1:4 rectangle 8/17, 30 deg rhombus sin 30 deg = 0.5 (all four corners)."""
    elements = np.array([[0, 1, 2, 3]])
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    rect = square * np.array([4.0, 1.0])
    s = np.sin(np.pi / 6)
    rhombus = np.array(
        [[0.0, 0.0], [1.0, 0.0], [1.0 + np.cos(np.pi / 6), s], [np.cos(np.pi / 6), s]]
    )
    for shape, q in ((square, 1.0), (rect, 8.0 / 17.0), (rhombus, 0.5)):
        assert np.max(np.abs(corner_qualities(shape, elements) - q)) <= 1e-12


def test_rezoning_needs_a_structured_mesh():
    from jaxform.config import ConfigError, load_config

    cfg = {
        "billet": {"diameter_mm": 4.0, "height_mm": 2.0},
        "time": {"dt_s": 1.0},
        "die": {"speed_mm_s": 0.1, "reduction": 0.1},
        "mesh": {"file": "some.msh", "rezone_quality": 0.3},
    }
    with pytest.raises(ConfigError, match="mesh.rezone_quality"):
        load_config(cfg)
    with pytest.raises(ConfigError, match="mesh.rezone_quality"):
        load_config({**cfg, "mesh": {"rezone_quality": 1.0}})
