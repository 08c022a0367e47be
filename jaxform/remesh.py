"""Remeshing: a new all-quad mesh of the deformed workpiece section, and the state on it.

Rezoning (:mod:`jaxform.rezone`) only moves the nodes of a structured grid, so a section
whose boundary folds or wraps a die corner ends with a degenerate element.  Remeshing
replaces the mesh (host NumPy and gmsh, between two converged steps):

1. **The boundary** (:func:`jaxform.mesh.boundary_polygon`): the deformed section's boundary as one
   counter-clockwise loop of node positions, each edge labelled with the set it belongs
   to (``axis``, ``symmetry``, ``top``, ``side``, ``inner``, ``outer``, ...).  Vertices
   that lie on the straight chord of their neighbours on the same set (to 1e-6 of the
   element size: the axis, the mid-plane, a flat die face) are dropped, so those parts
   are meshed anew at the wanted size; every other vertex stays a node.  The new mesh's
   boundary is therefore the old boundary polygon, and the material volume changes only
   by what the dropped vertices cut (reported per remesh, :class:`RemeshReport`).
2. **The new mesh** (:func:`jaxform.mesh.polygon_quads`, gmsh): all quadrilaterals, the
   size ``remesh.element_size_mm`` in the bulk and ``remesh.die_size_ratio`` times it at
   the vertices that touch a die (gap <= ``TOUCH_GAP_MM``) and at sharp boundary corners
   (a turn of more than 30 deg).  The sets are re-derived from the labels.  Where gmsh's
   recombination leaves triangles, finer sizes are tried, and last every element is
   split into quadrilaterals (:func:`jaxform.section_mesh.quads_of`; the report's
   ``mesher`` says which).
3. **The state** (:mod:`jaxform.transfer`): Gauss-point fields (stress, deformation
   resistance, equivalent plastic strain) by patch recovery and interpolation; nodal
   fields besides the displacement (q1q1 pressure, temperature) and the nodal rates of the
   predictor by interpolation; the contact tractions (multiplier over contact area) of the
   old candidates along the boundary, times the new contact areas; the contact status and
   the accumulated slip from the old boundary.  The deformed configuration becomes the
   new reference (u = 0, F_n = I), as in rezoning.

The scene on the new mesh (dofs, sets, sparsity pattern, its own compiled program) comes
from :func:`jaxform.scenes.scene_on_mesh`.  The transfer is a :class:`StateMap`, set up
once from the geometry and applied to the values: the forward run applies it with NumPy,
a gradient run (:mod:`jaxform.gradients`) with JAX and differentiates through it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import jax
import jax.numpy as jnp
import numpy as np

from jaxform.config import RemeshConfig
from jaxform.contact import TOUCH_GAP_MM, facets_in_contact
from jaxform.geometry import (
    mesh_change,
    min_quality,
    near_weights,
    nearest_on_segments,
    polygon_measure,
    tributary_areas,
    with_volume,
)
from jaxform.mesh import MeshError, boundary_edges, boundary_polygon
from jaxform.rezone import gap_function
from jaxform.scenes import scene_on_mesh
from jaxform.section_mesh import HELD, PUT_BACK_REACH, MesherHelp, quads_of, sized_polygon
from jaxform.transfer import StateMap, Transfer, gauss_weights


class RemeshError(RuntimeError):
    pass


@dataclass(frozen=True)
class RemeshReport:
    """What one remesh did: time, mesh sizes and qualities, the relative change of the
    material volume, the integral of the equivalent plastic strain (mm^3; plane strain
    mm^2) over the old and the new mesh, the host time it took (s; in a run with the
    padding to its capacity bucket) and the trigger."""

    time_s: float
    nodes_before: int
    nodes_after: int
    elements_before: int
    elements_after: int
    quality_before: float
    quality_after: float
    volume_change: float
    eqps_integral_before: float
    eqps_integral_after: float
    seconds: float
    trigger: str = ""  # what fired it (jaxform.triggers.causes: 'quality', 'steps', ...)
    mesher: MesherHelp = MesherHelp()  # what the mesher needed beyond its first try


def mesher_note(reports) -> str:
    """One line saying how many of the remeshes (:class:`RemeshReport`) needed more than
    the mesher's first try, of each kind, and the first such; "" where none did."""
    helped = [r for r in reports if r.mesher]
    if not helped:
        return ""
    counts = ", ".join(
        f"{sum(name in r.mesher.kinds() for r in helped)} {name}"
        for name in ("finer sizes", "split into quads", "a fold cut")
    )
    return (
        f"note: {len(helped)} of {len(reports)} remeshes needed more than the mesher's first "
        f"try ({counts}; first at t = {helped[0].time_s:.4g} s: {helped[0].mesher})"
    )


def new_section_mesh(scene, pos: np.ndarray, t: float, settings: RemeshConfig):
    """(the new mesh of the section whose nodes are at ``pos`` (time t), what the mesher
    needed: :func:`quads_of`).  Raises RemeshError."""
    try:
        gap_fn = None if scene.inputs.die is None else gap_function(scene.inputs.die, t)
        axi = scene.model.formulation.axisymmetric
        wanted = sized_polygon(scene.mesh, pos, gap_fn, settings, axi)
        mesh, how = quads_of(wanted.points, wanted.labels, wanted.sizes)
        how = replace(how, fold_cut_mm2=wanted.cut)  # also in the report's volume_change
    except MeshError as err:
        raise RemeshError(str(err)) from None
    if scene.inputs.die is None or not settings.onto_dies:
        return mesh, how
    return onto_dies(mesh, (wanted.points, wanted.touching), gap_fn, axi), how


def _polygon_vertex_of(loop_pos: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """For each boundary node (in loop order) the index of the polygon vertex it is, or -1
    for a node that gmsh added along an edge."""
    d = np.linalg.norm(loop_pos[:, None] - vertices[None], axis=2)
    k = np.argmin(d, axis=1)
    return np.where(d[np.arange(len(k)), k] <= 1e-9 * max(1.0, np.abs(vertices).max()), k, -1)


def onto_dies(mesh, polygon: tuple[np.ndarray, np.ndarray], gap_fn, axisymmetric: bool):
    """The mesh with the nodes gmsh added on polygon edges between two vertices that touch
    a die moved onto the die, and the material volume kept.

    An edge between two contact vertices is a chord of the die's surface: along a concave
    arc (a fillet the material fills) the added nodes sit off the die by the chord's
    sagitta, along a convex one inside it, so the first step on the new mesh begins with
    part of the contact open or overlapping and the die force dips (docs/remeshing.md).
    Each such node moves to its closest point on the die (where it lies within a quarter
    of its edge's length of it), and so does any node an edge placed inside a die (a
    chord across a convex die corner whose one end is no contact vertex); the axis and
    the mid-plane are never moved (an axis from the punch to the bottom die joins two
    contact vertices but is no chord).  The volume this adds or cuts is given back by moving the
    free surface (the boundary nodes off the dies, the axis and the mid-plane) along its
    outward normals by one distance, found by Newton steps (the first exact to first
    order) until the volume is the polygon's to 1e-13.

    Arguments:
        mesh: the new mesh; polygon: (its boundary polygon's vertices, which touch a die);
        gap_fn: ``points -> (gap, normal)`` of the dies at the remesh's time;
        axisymmetric: volumes by Pappus (True) or areas (plane strain)."""
    vertices, touching = polygon
    pos, labels, loop = boundary_polygon(mesh, mesh.coords)
    vertex = _polygon_vertex_of(pos, vertices)
    # for each loop node, the polygon vertices before and after it along the loop
    idx = np.arange(len(loop))
    is_v = vertex >= 0
    prev_v = np.maximum.accumulate(np.where(is_v, idx, -1))
    prev_v = np.where(prev_v < 0, np.nonzero(is_v)[0][-1], prev_v)
    nxt_v = np.minimum.accumulate(np.where(is_v, idx, len(idx))[::-1])[::-1]
    nxt_v = np.where(nxt_v >= len(idx), np.nonzero(is_v)[0][0], nxt_v)
    # the axis and the mid-plane are held by Dirichlet conditions: never moved (an axis
    # that runs from the punch to the bottom die joins two contact vertices, but it is
    # no chord of a die)
    held = np.zeros(len(loop), dtype=bool)
    for name in HELD:
        held |= np.isin(loop, np.asarray(mesh.node_sets.get(name, []), dtype=np.int64))
    gap_all, _ = gap_fn(pos)
    # a chord of the die between two contact vertices, or a node that an edge of the
    # polygon placed inside a die (a chord across a convex die corner, the punch's nose)
    on_chord = (
        ~is_v
        & ~held
        & ((touching[vertex[prev_v]] & touching[vertex[nxt_v]]) | (gap_all < -TOUCH_GAP_MM))
    )
    if not on_chord.any():
        return mesh
    g, n = gap_fn(pos[on_chord])
    chord = np.linalg.norm(pos[nxt_v[on_chord]] - pos[prev_v[on_chord]], axis=1)
    near = np.abs(g) <= 0.25 * chord
    coords = mesh.coords.copy()
    moved = loop[on_chord][near]
    coords[moved] -= (g[near])[:, None] * n[near]
    free_gap, _ = gap_fn(coords[loop])
    free = (free_gap > TOUCH_GAP_MM) & ~np.isin(loop, moved) & ~held
    target = float(np.sum(polygon_measure(mesh.coords[mesh.elements], axisymmetric)))
    reach = PUT_BACK_REACH * float(np.median(chord))  # the polygon's edges along the die
    weights = near_weights(coords[loop], mesh.coords[moved], reach)
    coords[loop] = with_volume(coords[loop], free, target, axisymmetric, weights)
    if min_quality(coords, mesh.elements) <= 0.0:  # a moved node folded a thin element
        return mesh
    return replace(mesh, coords=coords)


@dataclass(frozen=True)
class ContactMap:
    """The new candidates' multipliers, slip and status from the old candidates: each new
    candidate's nearest old boundary edge a -> b (old candidate indices, 0 with weight 0
    where an end is no candidate) and the weights of its two ends.  Multipliers: the
    tractions (multiplier / contact area) interpolated along the old boundary, times the
    new contact area; slip interpolated; status from the nearer end."""

    ends: np.ndarray  # (n_new_c, 2) old candidate index of the edge's ends
    multiplier_weights: np.ndarray  # (n_new_c, 2)
    slip_weights: np.ndarray  # (n_new_c, 2)
    status: np.ndarray  # (n_new_c,)

    def apply(self, multipliers, slip, xp=np):
        """(multipliers (n_new_c, 2), slip (n_new_c,)) of the old (n_c, 2) and (n_c,)."""
        if multipliers.shape[0] == 0:  # no old candidates: nothing to carry
            return xp.zeros((len(self.ends), 2)), xp.zeros(len(self.ends))
        lam = xp.einsum("pk,pki->pi", self.multiplier_weights, multipliers[self.ends])
        return lam, xp.sum(self.slip_weights * slip[self.ends], axis=1)


def contact_map(scene, new_scene, state, pos, new_pos) -> ContactMap:
    """The :class:`ContactMap` of a remesh at the old state ``state`` (nodes at ``pos``)."""
    lay, idx = scene.model.layout, scene.idx
    new_idx = new_scene.idx
    n_new = new_scene.model.layout.n_contact
    if lay.n_contact == 0 or n_new == 0:
        zero = np.zeros((n_new, 2))
        return ContactMap(np.zeros((n_new, 2), np.int64), zero, zero, np.zeros(n_new, np.int32))
    axi = scene.model.formulation.axisymmetric
    cn = np.asarray(idx.contact_nodes)
    status = np.asarray(state.contact_status)
    counted = facets_in_contact(status > 0, np.asarray(idx.contact_facets))
    area = tributary_areas(pos[cn], np.asarray(idx.contact_facets), axi, counted)
    per_area = np.where(area > 0, 1.0 / np.where(area > 0, area, 1.0), 0.0)
    # (old die, old node) -> candidate index: a candidate is a node, or a (node, die) pair
    # (:class:`jaxform.contact.EachDie`) whose values carry to the new pairs of its die
    die, new_die = np.asarray(idx.contact_die), np.asarray(new_idx.contact_die)
    cand = np.full((int(max(die.max(), new_die.max())) + 1, lay.n_nodes), -1)
    cand[die, cn] = np.arange(len(cn))
    edges = boundary_edges(scene.mesh.elements)
    new_cn = np.asarray(new_idx.contact_nodes)
    p = new_pos[new_cn]
    k, s, _ = nearest_on_segments(p, pos[edges[:, 0]], pos[edges[:, 1]])
    ends = cand[new_die[:, None], edges[k]]  # (n_new, 2)
    is_cand = ends >= 0
    ends = np.where(is_cand, ends, 0)
    along = np.column_stack([1.0 - s, s]) * is_cand
    st_end = np.where(is_cand, status[ends], 0)
    new_status = np.where(s < 0.5, st_end[:, 0], st_end[:, 1]).astype(np.int32)
    new_counted = facets_in_contact(new_status > 0, np.asarray(new_idx.contact_facets))
    new_area = tributary_areas(p, np.asarray(new_idx.contact_facets), axi, new_counted)
    lam_w = along * per_area[ends] * new_area[:, None]
    return ContactMap(ends, lam_w, along, new_status)


def eqps_integral(scene, pos: np.ndarray, eqps: np.ndarray) -> float:
    """Integral of the equivalent plastic strain over the section at positions ``pos``
    (mm^3 axisymmetric, mm^2 plane strain), by the 2 x 2 Gauss rule."""
    axi = scene.model.formulation.axisymmetric
    return float(np.sum(gauss_weights(pos, scene.mesh.elements, axi) * np.asarray(eqps)))


@dataclass(frozen=True)
class Remeshed:
    """A remesh: the scene on the new mesh, the state on it, what it did and the map that
    carried the state (:class:`StateMap`, for gradient runs)."""

    scene: object
    state: object
    report: RemeshReport
    transfer: StateMap


def remesh(scene, state, settings: RemeshConfig) -> Remeshed:
    """The new mesh and the state on it (:class:`Remeshed`) for a converged state of
    ``scene`` (its inputs are ``scene.inputs``).  Raises RemeshError."""
    start = time.perf_counter()
    lay = scene.model.layout
    host = jax.tree_util.tree_map(np.asarray, state)
    coords = np.asarray(scene.inputs.coords)
    pos = coords + lay.nodal(host.x)[:, :2]
    t = float(host.t)
    mesh, how = new_section_mesh(scene, pos, t, settings)
    new_scene = scene_on_mesh(scene, mesh)
    elements = np.asarray(scene.mesh.elements)
    move = Transfer(pos, elements, mesh.coords, mesh.elements)
    transfer = StateMap(
        lay,
        new_scene.model.layout,
        move,
        mesh.coords - move.nodal(pos),
        contact_map(scene, new_scene, host, pos, mesh.coords),
    )
    new_state, _ = transfer.apply(host, coords)
    new_state = jax.tree_util.tree_map(jnp.asarray, new_state)
    axi = scene.model.formulation.axisymmetric
    q0, q1, volume_change = mesh_change(pos, elements, mesh.coords, mesh.elements, axi)
    report = RemeshReport(
        time_s=t,
        nodes_before=lay.n_nodes,
        nodes_after=mesh.n_nodes,
        elements_before=len(elements),
        elements_after=mesh.n_elements,
        quality_before=q0,
        quality_after=q1,
        volume_change=volume_change,
        eqps_integral_before=eqps_integral(scene, pos, host.gauss.mat.eqps),
        eqps_integral_after=eqps_integral(new_scene, mesh.coords, new_state.gauss.mat.eqps),
        seconds=time.perf_counter() - start,
        mesher=how,
    )
    return Remeshed(new_scene, new_state, report, transfer)
