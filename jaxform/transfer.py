"""Transfer of fields between two quadrilateral meshes of the same material (host NumPy).

Rezoning (:mod:`jaxform.rezone`) and remeshing (:mod:`jaxform.remesh`) both carry the
state of a converged step from an old mesh to a new one.  The method, in two parts:

1. **Recovery to the old nodes** (:func:`gauss_to_nodes`): patch recovery, a linear
   least-squares fit to the Gauss values of the elements around each node, taken at the
   node (exact for every linear field of x), limited against overshoot.
2. **Interpolation at the new points** (:func:`locate`, :func:`interpolate`): each new
   node or Gauss point is found in the old mesh (element and natural coordinates, by
   Newton on the bilinear map) and the recovered nodal field is interpolated there.

A linear field of the position therefore transfers exactly (both parts are exact for it);
a smooth field with an error O(h^2) (tested: :mod:`tests.test_remesh`).  Points a little
outside the old mesh (a new boundary that cuts a corner of the old one by rounding) take
the value at the nearest point of the nearest element.
"""

from __future__ import annotations

import numpy as np

from jaxform import element as el

_A, _B = el._CORNERS[:, 0], el._CORNERS[:, 1]


def _shape(xi: np.ndarray) -> np.ndarray:
    """(..., 4) bilinear shape functions at natural coordinates xi (..., 2)."""
    return 0.25 * (1 + _A * xi[..., :1]) * (1 + _B * xi[..., 1:])


def _natural(points: np.ndarray, corners: np.ndarray, iterations: int = 12):
    """Natural coordinates (m, 2) of points (m, 2) in quads with corners (m, 4, 2) (Newton
    on the bilinear map, clipped to [-3, 3]^2 while it iterates) and how far each point is
    outside its quad: the excess of |xi| over 1 plus the miss over the quad's size."""
    xi = np.zeros((len(points), 2))
    for _ in range(iterations):
        n = _shape(xi)
        dxi = 0.25 * _A * (1 + _B * xi[:, 1:])
        deta = 0.25 * _B * (1 + _A * xi[:, :1])
        r = np.einsum("ma,mai->mi", n, corners) - points
        j = np.stack(
            [np.einsum("ma,mai->mi", dxi, corners), np.einsum("ma,mai->mi", deta, corners)], axis=-1
        )  # (m, i, k) = dx_i / dxi_k
        det = j[:, 0, 0] * j[:, 1, 1] - j[:, 0, 1] * j[:, 1, 0]
        det = np.where(np.abs(det) > 1e-300, det, 1e-300)
        d0 = (j[:, 1, 1] * r[:, 0] - j[:, 0, 1] * r[:, 1]) / det
        d1 = (-j[:, 1, 0] * r[:, 0] + j[:, 0, 0] * r[:, 1]) / det
        xi = np.clip(xi - np.column_stack([d0, d1]), -3.0, 3.0)
    miss = np.linalg.norm(np.einsum("ma,mai->mi", _shape(xi), corners) - points, axis=1)
    size = np.maximum(np.linalg.norm(corners[:, 2] - corners[:, 0], axis=1), 1e-300)
    return xi, np.maximum(np.abs(xi).max(axis=1) - 1.0, 0.0) + miss / size


def _candidates(points: np.ndarray, lo: np.ndarray, hi: np.ndarray):
    """(point, element) pairs whose element box [lo, hi] holds the point, found through a
    uniform grid of cells about the median box size (each box listed in the cells it
    covers, each point looked up in its cell): linear in the sizes, not P x E."""
    size = max(float(np.median(np.max(hi - lo, axis=1))), 1e-300)
    origin = lo.min(axis=0)
    c_lo = np.floor((lo - origin) / size).astype(np.int64)
    c_hi = np.floor((hi - origin) / size).astype(np.int64)
    n_cols = int(c_hi[:, 0].max()) + 1
    span = c_hi - c_lo + 1  # cells per box along r and z
    count = span[:, 0] * span[:, 1]
    el = np.repeat(np.arange(len(lo)), count)
    k = np.arange(len(el)) - np.repeat(np.cumsum(count) - count, count)
    cell = (c_lo[el, 1] + k // span[el, 0]) * n_cols + c_lo[el, 0] + k % span[el, 0]
    order = np.argsort(cell, kind="stable")
    cell, el = cell[order], el[order]
    pc = np.floor((points - origin) / size).astype(np.int64)
    inside_grid = (pc[:, 0] >= 0) & (pc[:, 0] < n_cols) & (pc[:, 1] >= 0)
    p_cell = np.where(inside_grid, pc[:, 1] * n_cols + pc[:, 0], -1)
    start, stop = np.searchsorted(cell, p_cell), np.searchsorted(cell, p_cell, side="right")
    n = stop - start
    pi = np.repeat(np.arange(len(points)), n)
    ei = el[np.repeat(start, n) + np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)]
    keep = np.all((points[pi] >= lo[ei]) & (points[pi] <= hi[ei]), axis=1)
    return pi[keep], ei[keep]


def locate(points: np.ndarray, pos: np.ndarray, elements: np.ndarray):
    """Element (p,) and natural coordinates (p, 2), clamped to [-1, 1]^2, of each point in
    the mesh (pos, elements): the element the point is least outside of.

    Candidates are the elements whose bounding box, grown by a quarter of its size,
    holds the point (:func:`_candidates`; the 8 nearest centroids where none does)."""
    points = np.asarray(points, dtype=float)
    xe = pos[elements]  # (ne, 4, 2)
    lo, hi = xe.min(axis=1), xe.max(axis=1)
    pad = 0.25 * (hi - lo).max(axis=1, keepdims=True)
    pi, ei = _candidates(points, lo - pad, hi + pad)
    none = np.ones(len(points), dtype=bool)
    none[pi] = False
    if none.any():
        centre = xe.mean(axis=1)
        lost = np.nonzero(none)[0]
        d = np.linalg.norm(points[lost][:, None] - centre[None], axis=2)
        near = np.argsort(d, axis=1)[:, : min(8, len(elements))]
        pi = np.concatenate([pi, np.repeat(lost, near.shape[1])])
        ei = np.concatenate([ei, near.ravel()])
    xi, out = _natural(points[pi], xe[ei])
    # per point the candidate with the least "outside"
    order = np.lexsort((out, pi))
    first = np.ones(len(order), dtype=bool)
    first[1:] = pi[order][1:] != pi[order][:-1]
    pick = order[first]
    best_e = np.zeros(len(points), dtype=np.int64)
    best_xi = np.zeros((len(points), 2))
    best_e[pi[pick]] = ei[pick]
    best_xi[pi[pick]] = xi[pick]
    return best_e, np.clip(best_xi, -1.0, 1.0)


def interpolate(nodal: np.ndarray, elements: np.ndarray, e: np.ndarray, xi: np.ndarray):
    """Bilinear interpolation of nodal values (n, ...) at natural coordinates xi (p, 2) of
    elements e (p,)."""
    return np.einsum("pa,pa...->p...", _shape(np.asarray(xi)), nodal[elements[e]])


def gauss_to_nodes(values: np.ndarray, pos: np.ndarray, elements: np.ndarray) -> np.ndarray:
    """Gauss-point values (ne, 4, ...) to nodal values (n, ...) by patch recovery: at each
    node, the least-squares linear fit a + b.(x - x_node) to the Gauss values of the
    elements around it, taken at the node (a).  Exact for a field linear in x.

    Limited: each value stays within the range of its patch's Gauss values widened by the
    fit's own change between the node and those points (so a linear field is untouched and
    an overshooting fit is cut back), and a field that is nowhere negative stays so."""
    values = np.asarray(values, dtype=float)
    elements = np.asarray(elements)
    n_nodes, shape = len(pos), values.shape[2:]
    gp = gauss_points(pos, elements)  # (ne, 4, 2)
    node = np.repeat(elements[:, :, None], 4, axis=2)  # (ne, corner, gp) -> node
    size = np.linalg.norm(pos[elements[:, 2]] - pos[elements[:, 0]], axis=1)
    h = np.zeros(n_nodes)
    np.maximum.at(h, elements.ravel(), np.repeat(size, 4))
    d = (gp[:, None, :, :] - pos[elements][:, :, None, :]) / h[node][..., None]  # (ne,4,4,2)
    p = np.concatenate([np.ones(d.shape[:-1] + (1,)), d], axis=-1)  # (ne, 4, 4, 3)
    a = np.zeros((n_nodes, 3, 3))
    np.add.at(a, node.ravel(), (p[..., :, None] * p[..., None, :]).reshape(-1, 3, 3))
    flat = values.reshape(values.shape[:2] + (-1,))  # (ne, 4, k)
    v = np.broadcast_to(flat[:, None], (len(elements), 4) + flat.shape[1:])  # (ne, c, g, k)
    b = np.zeros((n_nodes, 3, flat.shape[-1]))
    np.add.at(b, node.ravel(), (p[..., :, None] * v[..., None, :]).reshape(-1, 3, flat.shape[-1]))
    coef = np.linalg.solve(a, b)  # (n, 3, k)
    change = np.abs(np.einsum("ecgi,ecgik->ecgk", d, coef[node][..., 1:, :]))
    w = np.zeros((n_nodes, flat.shape[-1]))
    np.maximum.at(w, node.ravel(), change.reshape(-1, flat.shape[-1]))
    lo = np.full((n_nodes, flat.shape[-1]), np.inf)
    hi = np.full((n_nodes, flat.shape[-1]), -np.inf)
    np.minimum.at(lo, node.ravel(), v.reshape(-1, flat.shape[-1]))
    np.maximum.at(hi, node.ravel(), v.reshape(-1, flat.shape[-1]))
    out = np.clip(coef[:, 0], lo - w, hi + w)
    if flat.size and flat.min() >= 0.0:
        out = np.maximum(out, 0.0)
    return out.reshape((n_nodes,) + shape)


def gauss_points(pos: np.ndarray, elements: np.ndarray) -> np.ndarray:
    """(ne, 4, 2) positions of the Gauss points of every element."""
    return np.einsum("ga,eai->egi", el.N_GP, pos[elements])


def gauss_weights(pos: np.ndarray, elements: np.ndarray, axisymmetric: bool) -> np.ndarray:
    """(ne, 4) volume weights dV of the 2 x 2 Gauss rule (mm^3 axisymmetric, with 2 pi r;
    mm^2 plane strain), the NumPy twin of :func:`jaxform.element.gauss_geometry`'s (no JAX
    call, so no compile for each new mesh)."""
    xe = np.asarray(pos)[np.asarray(elements)]
    jac = np.einsum("gai,eaj->egji", el.DN_GP, xe)
    det = jac[..., 0, 0] * jac[..., 1, 1] - jac[..., 0, 1] * jac[..., 1, 0]
    w = det * el.GAUSS_WEIGHTS
    return w * 2.0 * np.pi * np.einsum("ga,ea->eg", el.N_GP, xe[..., 0]) if axisymmetric else w


class Transfer:
    """The transfer operators from an old mesh (old_pos, old_elements) to the nodes and the
    Gauss points of a new one (new_pos, new_elements), located once and applied to any
    number of fields."""

    def __init__(self, old_pos, old_elements, new_pos, new_elements):
        self.old_elements = np.asarray(old_elements)
        self.old_pos = np.asarray(old_pos)
        self.n_new_elements = len(new_elements)
        self._nodes = locate(new_pos, old_pos, self.old_elements)
        gp = gauss_points(new_pos, np.asarray(new_elements)).reshape(-1, 2)
        self._gauss = locate(gp, old_pos, self.old_elements)

    def nodal(self, values: np.ndarray) -> np.ndarray:
        """Old nodal values (n_old, ...) at the new nodes."""
        return interpolate(np.asarray(values), self.old_elements, *self._nodes)

    def gauss(self, values: np.ndarray) -> np.ndarray:
        """Old Gauss-point values (ne_old, 4, ...) at the new Gauss points (ne_new, 4, ...)."""
        values = np.asarray(values)
        nodal = gauss_to_nodes(values, self.old_pos, self.old_elements)
        out = interpolate(nodal, self.old_elements, *self._gauss)
        return out.reshape((self.n_new_elements, 4) + values.shape[2:])
