"""Rezoning: the element quality measure, quality-driven smoothing, state transfer.

References: corner quality of a square, rectangle and rhombus in closed form; exact
area / Pappus volume of a polygon whose boundary nodes slide along straight sides;
exactness of bilinear interpolation for fields linear in space (isoparametric quads
reproduce linear functions).
"""

import numpy as np
import pytest

from jaxform import element as el
from jaxform.mesh import rectangle
from jaxform.rezone import (_interpolate, _locate, _volumes, corner_qualities, gauss_to_nodes,
                            min_quality, smooth)

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
        for side, col, val in ((ids[0], 1, 0.0), (ids[-1], 1, 2.0), (ids[:, 0], 0, 0.0),
                               (ids[:, -1], 0, 3.0)):
            assert np.max(np.abs(new[side, col] - val)) <= 1e-12
        v0, v1 = _volumes(pos[elements], axi).sum(), _volumes(new[elements], axi).sum()
        assert abs(v1 / v0 - 1.0) <= 1e-12


def test_transfer_reproduces_linear_fields():
    """Gauss-point field f = 2 + 3 r - z on a distorted grid, carried to the Gauss points of
    the smoothed grid: exact (1e-12) wherever the new point lies in an old element away
    from the boundary (there the limiter to the old values' range never acts)."""
    m, pos, ids = _distorted_grid()
    elements = np.asarray(m.elements)
    new = smooth(pos, 6, 5, lambda p: (np.full(len(p), 10.0), np.tile([0.0, -1.0], (len(p), 1))))

    def field(p):
        return 2.0 + 3.0 * p[..., 0] - p[..., 1]

    gp_old = np.einsum("ga,eai->egi", el.N_GP, pos[elements])
    nodal = gauss_to_nodes(field(gp_old), elements, len(pos))
    gp_new = np.einsum("ga,eai->egi", el.N_GP, new[elements]).reshape(-1, 2)
    e, xi = _locate(gp_new, pos, elements)
    got = _interpolate(nodal, elements, e, xi)
    boundary = np.concatenate([ids[0], ids[-1], ids[:, 0], ids[:, -1]])
    interior = ~np.isin(elements[e], boundary).any(axis=1)
    assert interior.sum() >= 20
    assert np.max(np.abs(got[interior] - field(gp_new[interior]))) <= 1e-12
    # everywhere: no value outside the old range
    assert got.min() >= field(gp_old).min() - 1e-12 and got.max() <= field(gp_old).max() + 1e-12


def test_corner_quality_values():
    """Square 1, 1:4 rectangle 8/17, 30 deg rhombus sin 30 deg = 0.5 (all four corners)."""
    elements = np.array([[0, 1, 2, 3]])
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    rect = square * np.array([4.0, 1.0])
    s = np.sin(np.pi / 6)
    rhombus = np.array([[0.0, 0.0], [1.0, 0.0], [1.0 + np.cos(np.pi / 6), s],
                        [np.cos(np.pi / 6), s]])
    for shape, q in ((square, 1.0), (rect, 8.0 / 17.0), (rhombus, 0.5)):
        assert np.max(np.abs(corner_qualities(shape, elements) - q)) <= 1e-12


def test_rezoning_needs_a_structured_mesh():
    from jaxform.config import ConfigError, load_config

    cfg = {"billet": {"diameter_mm": 4.0, "height_mm": 2.0}, "time": {"dt_s": 1.0},
           "die": {"speed_mm_s": 0.1, "reduction": 0.1},
           "mesh": {"file": "some.msh", "rezone_quality": 0.3}}
    with pytest.raises(ConfigError, match="mesh.rezone_quality"):
        load_config(cfg)
    with pytest.raises(ConfigError, match="mesh.rezone_quality"):
        load_config({**cfg, "mesh": {"rezone_quality": 1.0}})
