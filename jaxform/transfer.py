"""Transfer of fields between two quadrilateral meshes of the same material.

Rezoning (:mod:`jaxform.rezone`) and remeshing (:mod:`jaxform.remesh`) both carry the
state of a converged step from an old mesh to a new one.  The method, in two parts:

1. **Recovery to the old nodes** (:class:`Recovery`): patch recovery, a linear
   least-squares fit to the Gauss values of the elements around each node, taken at the
   node (exact for every linear field of x), limited against overshoot.
2. **Interpolation at the new points** (:func:`locate`, :class:`Transfer`): each new
   node or Gauss point is found in the old mesh (element and natural coordinates, by
   Newton on the bilinear map) and the recovered nodal field is interpolated there.

A linear field of the position therefore transfers exactly (both parts are exact for it);
a smooth field with an error O(h^2) (tested: :mod:`tests.test_remesh`).  Points a little
outside the old mesh (a new boundary that cuts a corner of the old one by rounding) take
the value at the nearest point of the nearest element.

Both parts are set up once from the geometry (host NumPy) and then applied to the values
by NumPy or by traced JAX (argument ``xp``): a fixed, piecewise-linear map of the values
(linear where no limiter acts), which a gradient run differentiates
(:mod:`jaxform.gradients`).

:class:`StateMap` maps a whole simulation state with it, field by field as each field
declares what it is indexed over (:mod:`jaxform.fields`): the one map of a remesh, of a
rezoning (same topology, no contact map) and of a trim (:mod:`jaxform.process`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import jax
import numpy as np

from jaxform import element as el
from jaxform.fields import FieldMap, map_state

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


def _segment(xp, op: str, data, ids: np.ndarray, n: int):
    """Sum, max or min of the rows of ``data`` that share an id in ``ids`` (n ids): NumPy
    (``ufunc.at``) or JAX (``jax.ops.segment_*``, differentiable), so that one function
    serves the host transfer of a forward run and the traced one of a gradient run."""
    if xp is np:
        fill = {"sum": 0.0, "max": -np.inf, "min": np.inf}[op]
        out = np.full((n,) + data.shape[1:], fill)
        {"sum": np.add, "max": np.maximum, "min": np.minimum}[op].at(out, ids, data)
        return out
    import jax

    fn = {"sum": jax.ops.segment_sum, "max": jax.ops.segment_max, "min": jax.ops.segment_min}[op]
    return fn(data, ids, num_segments=n)


class Recovery:
    """Patch recovery on one mesh (pos, elements): Gauss-point values (ne, 4, ...) to nodal
    values (n, ...).  At each node, the least-squares linear fit a + b.(x - x_node) to
    the Gauss values of the elements around it, taken at the node (a): exact for a field
    linear in x.

    Limited: each value stays within the range of its patch's Gauss values widened by the
    fit's own change between the node and those points (so a linear field is untouched and
    an overshooting fit is cut back), and a field that is nowhere negative stays so.

    The geometry (the patches, the fit's weights) is set once; :meth:`apply` is then a
    piecewise-linear function of the values, for NumPy or traced JAX arrays."""

    def __init__(self, pos: np.ndarray, elements: np.ndarray):
        pos, elements = np.asarray(pos, dtype=float), np.asarray(elements)
        self.n_nodes, self.n_elements = len(pos), len(elements)
        gp = gauss_points(pos, elements)  # (ne, 4, 2)
        node = np.repeat(elements[:, :, None], 4, axis=2)  # (ne, corner, gp) -> node
        size = np.linalg.norm(pos[elements[:, 2]] - pos[elements[:, 0]], axis=1)
        h = np.zeros(len(pos))
        np.maximum.at(h, elements.ravel(), np.repeat(size, 4))
        d = (gp[:, None, :, :] - pos[elements][:, :, None, :]) / h[node][..., None]  # (ne,4,4,2)
        p = np.concatenate([np.ones(d.shape[:-1] + (1,)), d], axis=-1)  # (ne, 4, 4, 3)
        a = np.zeros((len(pos), 3, 3))
        np.add.at(a, node.ravel(), (p[..., :, None] * p[..., None, :]).reshape(-1, 3, 3))
        # the fit's coefficients are sum over the patch of (A_node^-1 p) v: its weights
        self.weights = np.einsum("eckij,eckj->ecki", np.linalg.inv(a)[node], p).reshape(-1, 3)
        self.node = node.ravel()  # (ne * 16,) the node of each (element, corner, gp) entry
        self.d = d.reshape(-1, 2)
        self.gp = np.tile(np.arange(4), 4 * len(elements))  # the entry's Gauss point
        self.el = np.repeat(np.arange(len(elements)), 16)

    def apply(self, values, xp=np):
        """Nodal values (n, ...) of Gauss-point values (ne, 4, ...)."""
        values = np.asarray(values, dtype=float) if xp is np else values
        shape = values.shape[2:]
        flat = values.reshape(values.shape[:2] + (-1,))  # (ne, 4, k)
        v = flat[self.el, self.gp]  # (entries, k)
        coef = _segment(
            xp, "sum", self.weights[:, :, None] * v[:, None, :], self.node, self.n_nodes
        )  # (n, 3, k); fmt: skip
        change = xp.abs(xp.einsum("mi,mik->mk", self.d, coef[self.node][:, 1:, :]))
        w = _segment(xp, "max", change, self.node, self.n_nodes)
        lo = _segment(xp, "min", v, self.node, self.n_nodes)
        hi = _segment(xp, "max", v, self.node, self.n_nodes)
        out = xp.clip(coef[:, 0], lo - w, hi + w)
        if flat.size:
            out = xp.where(xp.min(flat) >= 0.0, xp.maximum(out, 0.0), out)
        return out.reshape((self.n_nodes,) + shape)


def gauss_to_nodes(values: np.ndarray, pos: np.ndarray, elements: np.ndarray) -> np.ndarray:
    """Gauss-point values (ne, 4, ...) to nodal values (n, ...) by patch recovery
    (:class:`Recovery`)."""
    return Recovery(pos, elements).apply(np.asarray(values, dtype=float))


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
    number of fields, NumPy or traced JAX (``xp``): for a gradient run a fixed map."""

    def __init__(self, old_pos, old_elements, new_pos, new_elements):
        old_elements = np.asarray(old_elements)
        self.n_new_elements = len(new_elements)
        self.recovery = Recovery(old_pos, old_elements)
        e, xi = locate(new_pos, old_pos, old_elements)
        self.node_ids, self.node_w = old_elements[e], _shape(xi)  # (p, 4) each
        gp = gauss_points(new_pos, np.asarray(new_elements)).reshape(-1, 2)
        e, xi = locate(gp, old_pos, old_elements)
        self.gauss_ids, self.gauss_w = old_elements[e], _shape(xi)

    def nodal(self, values, xp=np):
        """Old nodal values (n_old, ...) at the new nodes."""
        values = np.asarray(values) if xp is np else values
        return xp.einsum("pa,pa...->p...", self.node_w, values[self.node_ids])

    def gauss(self, values, xp=np):
        """Old Gauss-point values (ne_old, 4, ...) at the new Gauss points (ne_new, 4, ...)."""
        values = np.asarray(values) if xp is np else values
        nodal = self.recovery.apply(values, xp)
        out = xp.einsum("pa,pa...->p...", self.gauss_w, nodal[self.gauss_ids])
        return out.reshape((self.n_new_elements, 4) + values.shape[2:])


@dataclass(frozen=True, eq=False)
class StateMap:
    """One remesh (or rezoning) as a fixed map from the old mesh's state to the new mesh's,
    set up once from the forward run's state (the located points, the recovery patches,
    the contact weights) and applied to NumPy values (the forward run) or traced JAX
    values (a gradient run, :mod:`jaxform.gradients`, which differentiates through it).

    :meth:`apply` ``(state, coords)`` -> ``(state, coords)``: the new reference coordinates
    are the old deformed positions (coords + u) interpolated at the new nodes (plus the
    fixed offset that makes them the new mesh's nodes exactly at the forward run's state:
    nodes a rounding outside the old mesh).  Each state field is mapped as its kind
    declares (:mod:`jaxform.fields`): the unknowns with u = 0 (the deformed configuration
    is the new reference), the other nodal fields (pressure, temperature) interpolated;
    the predictor's rates interpolated by a rezoning and zero on a new mesh, whose first
    step starts from the carried state (the old mesh's nodal rates are not the new
    discretization's flow at the die corners: docs/benchmarks.md); the Gauss state by
    :class:`Transfer` (patch recovery, then interpolation) with F = I, the other element
    fields (damage integrals) likewise; the candidates' multipliers, slip and status by
    ``contact`` (:class:`jaxform.remesh.ContactMap`; None: a map whose topology does not
    change, a rezoning, keeps the candidates' and facets' values as they are); time,
    friction work, heat and die wear carry over."""

    old: object  # jaxform.assembly.Layout
    new: object
    move: Transfer
    coords_offset: np.ndarray  # (n_new, 2) mm
    contact: object = None  # jaxform.remesh.ContactMap

    def apply(self, state, coords, xp=np):
        pos = coords + self.old.nodal(state.x)[:, :2]
        new_coords = self.move.nodal(pos, xp) + self.coords_offset
        return map_state(state, _Moved(self, state, xp)), new_coords


class _Moved(FieldMap):
    """The fields of ``state`` mapped by a :class:`StateMap` (``xp``: NumPy or JAX)."""

    def __init__(self, smap: StateMap, state, xp):
        self.m, self.xp = smap, xp
        self.old_multipliers = smap.old.node_multipliers(state.x)
        self.old_slip = state.slip_mm

    def _contact(self):
        return self.m.contact.apply(self.old_multipliers, self.old_slip, self.xp)

    def unknowns(self, x):
        m, xp = self.m, self.xp
        nodal, lam, facets = m.old.split(x)
        rest = m.move.nodal(nodal[:, 2:], xp)  # pressure, temperature
        new_nodal = xp.concatenate([xp.zeros((m.new.n_nodes, 2)), rest], axis=1)
        if m.contact is not None:
            lam, facets = self._contact()[0], xp.zeros(m.new.n_facets)
        return m.new.join(new_nodal, lam, facets, xp)

    def rates(self, x_rate):
        m, xp = self.m, self.xp
        if m.contact is not None:  # a new mesh starts its first step at rest
            return xp.zeros(m.new.n_dofs)
        nodal, lam, facets = m.old.split(x_rate)
        return m.new.join(m.move.nodal(nodal, xp), lam, facets, xp)

    def element(self, value):
        return self.m.move.gauss(value, self.xp)

    def gauss(self, value):
        eye = self.xp.broadcast_to(self.xp.eye(3), (self.m.new.n_elements, 4, 3, 3))
        return replace(value, F=eye, mat=jax.tree_util.tree_map(self.element, value.mat))

    def candidate(self, value):
        return value if self.m.contact is None else self._contact()[1]

    def status(self, value):
        if self.m.contact is None:
            return value
        return self.xp.asarray(self.m.contact.status.astype(value.dtype))
