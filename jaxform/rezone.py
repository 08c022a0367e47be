"""Rezoning: relocate the nodes of a distorted structured mesh and carry the state over.

A Lagrangian mesh cannot follow material that flows around a die corner: in the closed
die (configs/closed_die.toml) the top-surface element at the hub's convex fillet is
wrapped around the corner, one of its corners opens through 180 deg (a non-convex quad),
its tangent becomes nearly singular and Newton stagnates.  Rezoning keeps the mesh
*topology* (so the compiled program, the dofs and the sparsity pattern stay) and moves
the nodes (:func:`smooth`):

1. node by node, a quality-driven ("smart") smoothing: the node is offered the centre of
   its neighbours and short steps around it (nodes on a side of the logical grid: along
   that side, projected onto the die where they would enter it) and takes the best offer
   if it raises the worst corner quality of its elements; a side node's move must not
   change the material volume (by more than 1e-4 of its elements'), so free-surface
   corners are not cut off, except along the die; grid corners slide too unless they
   carry a Dirichlet condition (axis, mid-plane); the slivers that nodes sliding along
   a curved die or along the chords of a curved side cut off or add are then put back
   (:func:`restore_volume`: the free boundary nodes move along their normals by one
   common distance that makes the volume what it was before the rezoning, to 1e-12);
2. the state is carried to the new mesh: Gauss-point fields (stress, deformation
   resistance, equivalent plastic strain) are extrapolated to the nodes in each old
   element, averaged at the nodes, limited to the range of the Gauss values around the
   node, and interpolated (bilinear, in the old element that contains the new point);
   nodal pressures (q1q1) and the nodal velocities of the rate predictor likewise;
   contact multipliers, slip and status stay with their (boundary) node: the same
   :class:`jaxform.transfer.StateMap` as a remesh's, with no contact map;
3. the rezoned configuration becomes the new reference (u = 0, F_n = I): the material
   update is incremental (thesis: updated-Lagrangian stress update), so nothing else
   refers to the initial mesh.  Outputs keep measuring displacements from the initial
   mesh (:func:`jaxform.simulation.simulate`).

The trigger is the mesh quality (:func:`corner_qualities`): 2 det[a, b] / (|a|^2 + |b|^2)
for the two edges a, b at an element corner (1 for a square; it falls with skew and with
aspect ratio, and is < 0 for a non-convex quad), its minimum over the mesh checked after
every converged step inside the compiled chunk.

Rezoning is host-side NumPy between load steps: sensitivities
(jax.grad through a run) do not pass through it.  Only structured meshes (billet or ring
sections, not ``mesh.file``) can be rezoned.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import jax
import jax.numpy as jnp
import numpy as np

from jaxform.geometry import (
    corner_qualities,
    mesh_change,
    min_quality,  # noqa: F401  (the trigger's measure, named here too)
    polygon_measure,
)
from jaxform.transfer import StateMap, Transfer


class RezoneError(RuntimeError):
    pass


# ----------------------------------------------------------------------------------
# geometry


def _grid_ids(nr: int, nz: int) -> np.ndarray:
    return np.arange((nr + 1) * (nz + 1)).reshape(nz + 1, nr + 1)


def _grid_elements(ids: np.ndarray) -> np.ndarray:
    n0 = ids[:-1, :-1].ravel()
    nx = ids.shape[1] - 1
    return np.column_stack([n0, n0 + 1, n0 + nx + 2, n0 + nx + 1])


def _chain_points(chain: np.ndarray, s_target: np.ndarray) -> np.ndarray:
    seg = np.linalg.norm(np.diff(chain, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    return np.column_stack(
        [np.interp(s_target, s, chain[:, 0]), np.interp(s_target, s, chain[:, 1])]
    )


@dataclass(frozen=True)
class Smoothing:
    """Settings of :func:`smooth`: at most ``sweeps`` sweeps; a side node's moves change
    the volume of its elements by at most ``volume_tol`` of theirs; sweeps end when no
    node moves by more than ``move_tol`` x its element size; a node within
    ``contact_tol`` mm of the die is on it; ``touching`` the sides (bottom, top, left,
    right) the die may touch; ``die_volume_free``: nodes on the die slide along it with
    no volume limit (False: the side nodes' limit holds for them too)."""

    sweeps: int = 100
    volume_tol: float = 1e-4
    move_tol: float = 1e-4
    contact_tol: float = 1e-6
    touching: tuple[bool, bool, bool, bool] = (False, True, True, True)
    die_volume_free: bool = True


def smooth(
    pos: np.ndarray,
    nr: int,
    nz: int,
    gap_fn,
    axisymmetric: bool = True,
    pinned=(),
    settings: Smoothing = Smoothing(),
) -> np.ndarray:
    """Quality-driven ("smart") smoothing of a structured grid.

    Each node in turn is offered: the centre of its neighbours (interior: the mean of the
    four grid neighbours; side nodes: the arc-length midpoint of its two neighbours along
    the side), the half and quarter way there, and short steps in 8 directions (side
    nodes: along the side) of 1/4 and 1/16 of the local element size; side points that
    land inside the die are projected onto it.  The best offer is taken if it raises the
    smallest corner quality (:func:`corner_qualities`) of the elements around the node,
    pushes no node into the die, and changes the volume of the material (the elements
    around a side node) by at most ``volume_tol`` of theirs, in that move and in all of
    that node's moves together (interior moves never change it).  Exception: a side node
    that lies on the die (|gap| <= ``contact_tol`` mm) between two neighbours on the die
    slides along the die itself (its offers are projected onto it), with no volume limit
    (unless ``settings.die_volume_free`` is False):
    the boundary there is the die, and the volume between the die and the chords of the
    boundary (material that a convex die corner overlaps) is no material.  A corner of
    the grid slides like a side node along its two neighbours on the boundary (the sides
    meet at a smooth point when a free surface folds onto the die, as the ring's sides at
    high friction) unless it is in ``pinned`` (nodes with a Dirichlet condition: sliding
    would move them off the axis or the mid-plane).
    Sweeps end when no node moves by more than ``move_tol`` x its element size
    (:class:`Smoothing`); ``gap_fn(points (m, 2)) -> (g (m,), n (m, 2))``."""
    sweeps, volume_tol, move_tol = settings.sweeps, settings.volume_tol, settings.move_tol
    contact_tol = settings.contact_tol
    ids = _grid_ids(nr, nz)
    elements = _grid_elements(ids)
    x = pos.copy()
    around = [[] for _ in range(len(x))]
    for e, nodes in enumerate(elements):
        for a in nodes:
            around[a].append(e)
    patch = [elements[np.array(a)] for a in around]
    loop = _boundary_loop(nr, nz)
    side_id = np.concatenate([np.full(nr, 0), np.full(nz, 3), np.full(nr, 1), np.full(nz, 2)])
    touch = np.asarray(settings.touching)[side_id]  # of each loop node's side (corners: the first)
    corner_mask = np.isin(loop, [ids[0, 0], ids[0, -1], ids[-1, 0], ids[-1, -1]])
    nb = {
        int(a): (
            int(loop[m - 1]),
            int(loop[(m + 1) % len(loop)]),
            bool(touch[m] and touch[m - 1]),
            bool(corner_mask[m]),
        )
        for m, a in enumerate(loop)
    }
    v_start = {a: polygon_measure(x[patch[a]], axisymmetric).sum() for a in nb}
    dirs = np.array([[np.cos(a), np.sin(a)] for a in np.linspace(0, 2 * np.pi, 8, endpoint=False)])
    steps = np.array([0.25, 0.0625])
    fractions = np.array([1.0, 0.5, 0.25])
    for _ in range(sweeps):
        moved = 0.0
        for a in range(len(x)):
            pe = patch[a]
            h_loc = np.mean(np.linalg.norm(x[pe].reshape(-1, 2) - x[a], axis=1)) * 4.0 / 3.0
            on_side = a in nb
            on_die = False
            if on_side:
                prev, nxt, may_touch, is_corner = nb[a]
                chain = x[[prev, a, nxt]]
                if may_touch:
                    on_die = bool(np.all(np.abs(gap_fn(chain)[0]) <= contact_tol))
                if is_corner and a in pinned:
                    continue
                s = np.concatenate(
                    [[0.0], np.cumsum(np.linalg.norm(np.diff(chain, axis=0), axis=1))]
                )
                s_try = np.concatenate(
                    [
                        s[1] + fractions * (0.5 * s[2] - s[1]),
                        s[1] + np.outer([-1.0, 1.0], steps * h_loc).ravel(),
                    ]
                )
                cand = _chain_points(chain, s_try[(s_try > 0.0) & (s_try < s[2])])
                if may_touch and len(cand):
                    g, n = gap_fn(cand)
                    cand = cand - (g if on_die else np.minimum(g, 0.0))[:, None] * n
            else:
                j, i = divmod(a, nr + 1)
                centre = 0.25 * (
                    x[ids[j, i - 1]] + x[ids[j, i + 1]] + x[ids[j - 1, i]] + x[ids[j + 1, i]]
                )
                cand = np.vstack(
                    [
                        x[a] + fractions[:, None] * (centre - x[a]),
                        x[a] + (steps[:, None, None] * h_loc * dirs).reshape(-1, 2),
                    ]
                )
            if not len(cand):
                continue
            pts = np.vstack([x[a][None], cand])  # row 0: where the node is now
            corners_xy = np.broadcast_to(x[pe], (len(pts),) + pe.shape + (2,)).copy()
            mine = pe == a
            corners_xy[:, mine] = pts[:, None, :]
            q = corner_qualities(corners_xy, None).min(axis=(1, 2))
            g = gap_fn(pts)[0]
            ok = (q > q[0] + 1e-9) & (g >= min(g[0], 0.0) - 1e-12)
            if on_side and not (on_die and settings.die_volume_free):
                v = polygon_measure(corners_xy, axisymmetric).sum(axis=1)
                ok &= (np.abs(v - v[0]) <= volume_tol * abs(v[0])) & (
                    np.abs(v - v_start[a]) <= volume_tol * abs(v_start[a])
                )
            if not ok.any():
                continue
            best = int(np.argmax(np.where(ok, q, -np.inf)))
            moved = max(moved, float(np.linalg.norm(pts[best] - x[a])) / h_loc)
            x[a] = pts[best]
        if moved < move_tol:
            break
    return x


def rezoned_positions(
    pos: np.ndarray, nr: int, nz: int, die, t: float, axisymmetric: bool = True, pinned=()
) -> np.ndarray:
    """New nodal positions (n, 2) for the current positions ``pos`` of the grid."""
    gap_fn = gap_function(die, t)
    pinned = set(int(a) for a in pinned)
    elements = _grid_elements(_grid_ids(nr, nz))
    v_old = polygon_measure(pos[elements], axisymmetric).sum()
    # nodes on the die slide freely first; where the free surface cannot take back what
    # that cut off (a die nearly filled), they slide under the side nodes' volume limit
    for settings in (Smoothing(), Smoothing(die_volume_free=False)):
        new = smooth(pos, nr, nz, gap_fn, axisymmetric, pinned, settings)
        new = restore_volume(new, nr, nz, v_old, gap_fn, axisymmetric, pinned)
        if abs(polygon_measure(new[elements], axisymmetric).sum() / v_old - 1.0) <= 1e-10:
            break
    return new


def gap_function(die, t: float):
    """``gap_fn(points (m, 2)) -> (g (m,), n (m, 2))``: the die's gap and outward normal at
    points (host NumPy in and out) at time t."""
    t = jnp.asarray(t)

    def gap_fn(points):
        # padded to whole batches so that one compiled program serves every call
        m = len(points)
        pad = np.broadcast_to(points[:1], (-m % _BATCH + m, 2)).copy()
        pad[:m] = points
        out = [
            _gaps_at(die, jnp.asarray(pad[k : k + _BATCH]), t) for k in range(0, len(pad), _BATCH)
        ]
        g, n = (np.concatenate([np.asarray(o[i]) for o in out]) for i in (0, 1))
        return g[:m], n[:m]

    return gap_fn


def _boundary_loop(nr: int, nz: int) -> np.ndarray:
    """The grid's boundary nodes as one counter-clockwise loop: bottom, right, top, left."""
    ids = _grid_ids(nr, nz)
    return np.concatenate([ids[0, :-1], ids[:-1, -1], ids[-1, :0:-1], ids[:0:-1, 0]])


def restore_volume(
    pos: np.ndarray,
    nr: int,
    nz: int,
    v_target: float,
    gap_fn,
    axisymmetric: bool = True,
    pinned=(),
    contact_tol: float = 1e-6,
) -> np.ndarray:
    """Positions with the material volume (area) brought back to ``v_target``: the free
    boundary nodes (neither pinned by a Dirichlet condition nor on the die) move along
    their outward normals by one common distance d, solved by Newton on the volume (a
    polynomial of degree <= 3 in d, to 1e-12 of it).  Smoothing moves side nodes along
    chords of a curved
    boundary and slides nodes along a curved die, which cuts or adds thin slivers; this
    puts the lost volume back where the boundary is free.  A node that the offset would
    push into the die is left out and d solved again.  Without free nodes the positions
    are returned as they are (the caller reports the volume change)."""
    elements = _grid_elements(_grid_ids(nr, nz))
    loop = _boundary_loop(nr, nz)
    x = pos.copy()
    edge = np.roll(x[loop], -1, axis=0) - x[loop]  # edge m joins loop[m] -> loop[m + 1]
    en = np.column_stack([edge[:, 1], -edge[:, 0]])  # outward for a counter-clockwise loop
    en /= np.maximum(np.linalg.norm(en, axis=1, keepdims=True), 1e-300)
    normal = en + np.roll(en, 1, axis=0)  # the two edges at each loop node
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    free = np.array([int(a) not in pinned for a in loop])
    free &= gap_fn(x[loop])[0] > contact_tol
    scale = abs(v_target)
    for _ in range(4):
        if not free.any():
            return pos
        dirs = np.zeros_like(x)
        dirs[loop[free]] = normal[free]

        def vol(d):
            return polygon_measure((x + d * dirs)[elements], axisymmetric).sum() - v_target

        d = 0.0
        h = 1e-7 * np.sqrt(scale / max(len(loop), 1))
        for _ in range(30):
            f = vol(d)
            if abs(f) <= 1e-12 * scale:
                break
            d -= f * 2.0 * h / (vol(d + h) - vol(d - h))
        moved = x + d * dirs
        inside = free & (gap_fn(moved[loop])[0] < 0.0)
        if not inside.any():
            return moved
        free &= ~inside
    return pos


_BATCH = 32


@jax.jit
def _gaps_at(die, points, t):
    return jax.vmap(lambda p: die.gap(p, t)[:2])(points)


@dataclass(frozen=True)
class RezoneReport:
    time_s: float
    quality_before: float
    quality_after: float
    volume_change: float  # relative change of the material volume (chords across corners)
    improved: bool = True  # False: no node move raised the quality; the mesh was kept
    # (n_nodes, 2) the nodes' positions after rezoning (mm; None where the mesh was kept):
    # where material lines are located again (jaxform.flowlines)
    positions: np.ndarray | None = None


def rezone(scene, state, inputs):
    """(new state, new inputs, RezoneReport) for a scene's converged state: the nodes
    moved (:func:`rezoned_positions`), the state carried by the same map as a remesh's
    (:class:`jaxform.remesh.StateMap`, one whose topology does not change: the
    candidates keep their multipliers, slip and status)."""
    if scene.grid is None:
        raise RezoneError("rezoning needs a structured mesh (mesh.file = '')")
    nr, nz = scene.grid
    lay = scene.model.layout
    elements = np.asarray(scene.mesh.elements)
    ref = np.asarray(inputs.coords)
    host = jax.tree_util.tree_map(np.asarray, state)
    pos = ref + lay.nodal(host.x)[:, :2]
    t = float(host.t)
    pinned = np.unique(np.asarray(scene.idx.fixed) // lay.n_fields)
    axi = scene.model.formulation.axisymmetric
    new_pos = rezoned_positions(pos, nr, nz, inputs.die, t, axi, pinned)
    q_old, q_new, volume_change = mesh_change(pos, elements, new_pos, elements, axi)
    if not q_new > q_old:  # nothing to gain: the caller goes on with the mesh as it is
        return state, inputs, RezoneReport(t, q_old, q_old, 0.0, improved=False)
    # new Gauss points and nodes, located in the old (current) mesh
    move = Transfer(pos, elements, new_pos, elements)
    smap = StateMap(lay, lay, move, new_pos - move.nodal(pos))
    new_state, _ = smap.apply(host, ref)
    new_state = jax.tree_util.tree_map(jnp.asarray, new_state)
    new_inputs = replace(inputs, coords=jnp.asarray(new_pos))
    return new_state, new_inputs, RezoneReport(t, q_old, q_new, volume_change, True, new_pos)
