"""Host-side quantities derived from converged states (NumPy): what engineers read.

* the extra history columns of a run: the workpiece's own
  (:meth:`jaxform.workpieces.Workpiece.extra_history`: ring diameters, a membrane's tip
  displacement), ``flash_volume_mm3`` (the material beyond ``die.part_radius_mm``) and, for
  closed dies, ``die_fill`` = volume of the cavity that the
  material occupies / volume of the cavity enclosed by the (rounded, :mod:`jaxform.dies`)
  die profile, the axis and the mid-plane (Pappus: V = 2 pi * integral of r dA);
* contact profiles along the die: normal pressure and shear traction (multiplier over
  the node's contact area, MPa), status (0 open, 1 stick, 2 slip), accumulated slip;
* the pressure-oscillation measure of equal-order u-p (q1q1): how far the nodal pressure
  departs from its element-patch average (checkerboard modes).
"""

from __future__ import annotations

import numpy as np

from jaxform.contact import facets_in_contact
from jaxform.dies import sample_rounded
from jaxform.fill import conformed_edges
from jaxform.geometry import nearest_on_segments, polygon_measure, tributary_areas
from jaxform.laps import fold_columns
from jaxform.mesh import boundary_edges


def positions(scene, x) -> np.ndarray:
    """Current nodal positions (mm): the scene's reference ``inputs.coords`` (the mesh, or a
    preform that replaced it) plus the displacement in ``x``."""
    u, _, _ = nodal_fields(scene, x)
    return np.asarray(scene.inputs.coords) + u


def nodal_fields(scene, x: np.ndarray):
    """Split an unknown vector into displacement (n, 2), nodal pressure (n,) or None, and
    the multipliers."""
    lay = scene.model.layout
    nodal = lay.nodal(np.asarray(x))
    pressure = None if lay.pressure_column is None else nodal[:, lay.pressure_column]
    return nodal[:, :2], pressure, np.asarray(lay.node_multipliers(np.asarray(x)))


def nodal_temperature(scene, x: np.ndarray) -> np.ndarray | None:
    """(n_nodes,) nodal temperatures (K) of a coupled thermal run, else None (the unknown
    is the change from the billet temperature)."""
    lay = scene.model.layout
    if not lay.temperature:
        return None
    return lay.temperatures(np.asarray(x), float(scene.inputs.thermal.billet_temperature_K))


def nodal_volumes(scene) -> np.ndarray:
    """(n_nodes,) int N_a dV0 on the reference mesh (mm^3; plane strain mm^2): the nodes'
    shares of the material, the weights of the lumped heat capacity."""
    from jaxform import element as el
    from jaxform.transfer import gauss_weights

    coords, elements = np.asarray(scene.inputs.coords), np.asarray(scene.mesh.elements)
    weights = gauss_weights(coords, elements, scene.model.formulation.axisymmetric)
    return np.bincount(elements.ravel(), (weights @ el.N_GP).ravel(), len(coords))


# the heat of a coupled run so far (mJ), the order of SimState.heat_mJ
HEAT_COLUMNS = ("heat_stored_mJ", "heat_plastic_mJ", "heat_to_dies_mJ", "heat_to_air_mJ")


def temperature_history(scene, xs: np.ndarray) -> dict[str, np.ndarray]:
    """mean (weighted by the material each node carries), min and max nodal temperature
    (K) of every row; {} without a temperature field."""
    if scene.model.layout.temperature_column is None:
        return {}
    temps = np.stack([nodal_temperature(scene, x) for x in xs])
    w = nodal_volumes(scene)
    return dict(
        mean_temperature_K=temps @ w / w.sum(),
        min_temperature_K=temps.min(axis=1),
        max_temperature_K=temps.max(axis=1),
    )


def material_volume(scene, pos: np.ndarray) -> float:
    """Volume (axisymmetric, mm^3) or area (plane strain, mm^2) of the material at nodal
    positions ``pos``."""
    axi = scene.model.formulation.axisymmetric
    return float(np.sum(polygon_measure(pos[np.asarray(scene.mesh.elements)], axi)))


def material_beyond(scene, pos: np.ndarray, radius: float) -> float:
    """Volume (axisymmetric, mm^3; plane strain, mm^2) of the material at r >= radius:
    the elements wholly beyond it, plus each element the radius cuts clipped to that
    half-plane (a few per row: the host loop runs over those alone)."""
    axi = scene.model.formulation.axisymmetric
    quads = pos[np.asarray(scene.mesh.elements)]
    r_min, r_max = quads[..., 0].min(axis=1), quads[..., 0].max(axis=1)
    total = float(np.sum(np.abs(polygon_measure(quads[r_min >= radius], axi))))
    for poly in quads[(r_min < radius) & (r_max > radius)]:
        part = _clip_above(poly[:, ::-1], radius)[:, ::-1]
        if len(part) >= 3:
            total += abs(float(polygon_measure(part, axi)))
    return total


def _clip_above(poly: np.ndarray, z0: float = 0.0) -> np.ndarray:
    """Sutherland-Hodgman clip of a closed polygon to the half-plane z >= z0."""
    out = []
    for a, b in zip(poly, np.roll(poly, -1, axis=0)):
        ina, inb = a[1] >= z0, b[1] >= z0
        if ina:
            out.append(a)
        if ina != inb:
            s = (z0 - a[1]) / (b[1] - a[1])
            out.append(a + s * (b - a))
    return np.array(out) if out else np.zeros((0, 2))


def cavity_polygon(scene, t: float) -> np.ndarray:
    """The part's cavity at time t (die profile, mid-plane, axis; full height: the top
    die's profile, the bottom die's and the axis; up to ``die.part_radius_mm`` where one
    is set) as a counter-clockwise polygon."""
    die = scene.inputs.die
    names = die.names
    top, *_ = surfaces = [
        sample_rounded(d.points, d.corner_radius) - np.array([0.0, d.travel_at(t)])
        for d in die.members
    ]
    if "bottom" in names:  # walked from the outside to the axis: the loop closes on the axis
        poly = np.vstack([top, surfaces[names.index("bottom")]])
    else:
        poly = _clip_above(np.vstack([[0.0, 0.0], top, [top[-1, 0], 0.0]]))
    r_part = scene.settings.die.part_radius_mm
    if r_part > 0.0 and len(poly):
        poly = -_clip_above(-poly[:, ::-1], -r_part)[:, ::-1]  # keep r <= r_part
    if len(poly) >= 3 and _signed_area(poly) < 0.0:
        poly = poly[::-1]
    return poly


def cavity_volume(scene, t: float) -> float:
    poly = cavity_polygon(scene, t)
    if len(poly) < 3:
        return 0.0
    return abs(float(polygon_measure(poly, scene.model.formulation.axisymmetric)))


def _signed_area(poly: np.ndarray) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _inside(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Even-odd point-in-region test against the boundary edges a -> b (vectorized)."""
    px, py = points[:, None, 0], points[:, None, 1]
    crosses = (a[None, :, 1] > py) != (b[None, :, 1] > py)
    with np.errstate(divide="ignore", invalid="ignore"):
        xc = a[None, :, 0] + (py - a[None, :, 1]) * (b[None, :, 0] - a[None, :, 0]) / (
            b[None, :, 1] - a[None, :, 1]
        )
    return np.sum(crosses & (px < xc), axis=1) % 2 == 1


def _clipped_boundary_integral(p0, p1, a, b, keep_on_boundary, tol, axisymmetric):
    """Green's-theorem integral (int r^2/2 dz, axisymmetric; int r dz, plane strain) over
    the parts of the directed edges p0 -> p1 inside the region bounded by the edges a -> b
    (parts on that boundary, within tol, count as inside when ``keep_on_boundary``).

    Each edge is split where it crosses the other boundary and where a vertex of the other
    boundary lies on it (within tol): where the boundaries run together along a die wall
    and part ways at such a vertex, a crossing test alone misses the vertex by round-off
    and leaves the edge in one piece, counted (or not) whole."""
    d, e = p1 - p0, b - a
    den = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]
    w = a[None] - p0[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[..., 0] * e[None, :, 1] - w[..., 1] * e[None, :, 0]) / den
        u = (w[..., 0] * d[:, None, 1] - w[..., 1] * d[:, None, 0]) / den
        s = np.sum(w * d[:, None, :], axis=-1) / np.sum(d * d, axis=-1)[:, None]
    hit = (np.abs(den) > 0) & (t > 0) & (t < 1) & (u >= 0) & (u <= 1)
    off = np.linalg.norm(w - s[..., None] * d[:, None, :], axis=-1)
    on = (off <= tol) & (s > 0) & (s < 1)  # a vertex of the other boundary on the edge
    # every edge's split parameters in one sorted row (NaN where none: sorted last); the
    # pieces between neighbouring finite parameters, all edges at once
    cuts = np.concatenate([np.where(hit, t, np.nan), np.where(on, s, np.nan)], axis=1)
    ends = np.broadcast_to(np.array([0.0, 1.0]), (len(p0), 2))
    ts = np.sort(np.concatenate([ends, cuts], axis=1), axis=1)
    valid = np.isfinite(ts[:, 1:])
    k = np.broadcast_to(np.arange(len(p0))[:, None], valid.shape)[valid]
    t0, t1 = ts[:, :-1][valid], ts[:, 1:][valid]
    q0, q1 = p0[k] + t0[:, None] * d[k], p0[k] + t1[:, None] * d[k]
    mid = 0.5 * (q0 + q1)
    near = nearest_on_segments(mid, a, b)[2] <= tol
    keep = np.where(near, keep_on_boundary, _inside(mid, a, b))
    r0, z0, r1, z1 = q0[:, 0], q0[:, 1], q1[:, 0], q1[:, 1]
    if axisymmetric:
        part = (z1 - z0) * (r0 * r0 + r0 * r1 + r1 * r1) / 6.0
    else:
        part = (z1 - z0) * (r0 + r1) / 2.0
    return float(np.sum(part[keep]))


def overlap_depth(die_points: np.ndarray, pos: np.ndarray, edges: np.ndarray) -> float:
    """How deep (mm) the die reaches into the material: the largest distance from the
    material's boundary of a die point inside the material, 0 where none is.

    die_points: (k, 2) a dense sampling of the die surface; pos: (n, 2) nodal positions;
    edges: (n_b, 2) the material's boundary edges (:func:`jaxform.mesh.boundary_edges`)."""
    a, b = pos[edges[:, 0]], pos[edges[:, 1]]
    inside = _inside(die_points, a, b)
    if not inside.any():
        return 0.0
    return float(np.max(nearest_on_segments(die_points[inside], a, b)[2]))


def die_overlap(scene, pos: np.ndarray, t: float) -> float:
    """The die's overlap of the material at time t (mm): contact holds the workpiece
    nodes on the die, so what remains is a convex die corner reaching between two
    contact nodes into a facet.  The rounded profile is sampled at 64 points per arc
    (the depth is then resolved to ~1e-3 of the arc's sagitta); the deepest of the dies."""
    edges = boundary_edges(scene.mesh.elements)
    return max(
        overlap_depth(
            sample_rounded(d.points, d.corner_radius, per_arc=64) - np.array([0.0, d.travel_at(t)]),
            pos,
            edges,
        )
        for d in scene.inputs.die.members
    )


def filled_volume(scene, pos: np.ndarray, t: float) -> float:
    """Volume of the cavity that the material occupies: the intersection of material and
    cavity, by Green's theorem over the material's boundary inside the cavity and the
    cavity's boundary inside the material (material that a convex die corner overlaps
    between two contact nodes does not count; a boundary shared within 1e-9 of the cavity
    size counts once).

    The intersection holds no more than the cavity nor than the material on the part's
    side of ``die.part_radius_mm`` (each element clipped there): the result is capped at
    both, which the boundary integral could pass where long stretches of the material's
    boundary run along the die's within round-off (a generated closed die read a fill of
    1.089 at the end of its stroke, its material 0.9972 of the cavity)."""
    cav = cavity_polygon(scene, t)
    if len(cav) < 3:
        return 0.0
    axi = scene.model.formulation.axisymmetric
    edges = boundary_edges(scene.mesh.elements)
    surfaces = die_outlines(scene, t, reach_mm=0.0).values()
    m0, m1, sliver_polygons = conformed_edges(pos, edges, surfaces)
    c0, c1 = cav, np.roll(cav, -1, axis=0)
    tol = 1e-9 * max(float(np.ptp(cav, axis=0).max()), 1.0)
    total = _clipped_boundary_integral(m0, m1, c0, c1, True, tol, axi) + _clipped_boundary_integral(
        c0, c1, m0, m1, False, tol, axi
    )
    green = abs(2.0 * np.pi * total) if axi else abs(total)
    die = scene.settings.die
    radius = die.part_radius_mm if die is not None and die.part_radius_mm > 0.0 else np.inf
    part = material_volume(scene, pos)
    if radius < np.inf:
        part -= material_beyond(scene, pos, radius)
    # the slivers conforming adds (the overlaps it removes) at r <= radius
    part += sum(_measure_within(poly, radius, axi) for poly in sliver_polygons)
    return min(green, part, abs(float(polygon_measure(cav, axi))))


def _measure_within(poly: np.ndarray, radius: float, axisymmetric: bool) -> float:
    """Signed measure of the part of the polygon at r <= radius (its orientation kept)."""
    if poly[:, 0].max() > radius:  # z >= -R of the polygon turned and mirrored: r <= R
        poly = -_clip_above(-poly[:, ::-1], -radius)[:, ::-1]
    return float(polygon_measure(poly, axisymmetric)) if len(poly) >= 3 else 0.0


def extra_history(scene, xs: np.ndarray, times: np.ndarray) -> dict[str, np.ndarray]:
    """The history columns a scene adds to every run: its workpiece's
    (:meth:`jaxform.workpieces.Workpiece.extra_history`), for a die scene
    ``die_overlap_mm`` (:func:`die_overlap`) and the free surface's narrowest wedge and
    pocket (:func:`jaxform.laps.fold_columns`), for a closed die ``die_fill`` (0..1),
    with a part radius ``flash_volume_mm3``, with a temperature field the mean, min and
    max temperature (:func:`temperature_history`)."""
    coords = np.asarray(scene.inputs.coords)
    pos = np.stack([positions(scene, x) for x in xs])
    out = dict(scene.workpiece.extra_history(scene.mesh, pos, pos - coords))
    die = scene.settings.die
    if die is not None and die.closed:
        out["die_fill"] = np.array(
            [
                filled_volume(scene, p, t) / max(cavity_volume(scene, t), 1e-300)
                for p, t in zip(pos, times)
            ]
        )
    if die is not None:
        out["die_overlap_mm"] = np.array([die_overlap(scene, p, t) for p, t in zip(pos, times)])
    if die is not None and die.part_radius_mm > 0.0:
        halves = 2.0 if scene.symmetric_z else 1.0
        out["flash_volume_mm3"] = np.array(
            [halves * material_beyond(scene, p, die.part_radius_mm) for p in pos]
        )
    if die is not None:
        out.update(fold_columns(scene, pos, times))
    out.update(temperature_history(scene, xs))
    return out


def _extended(poly: np.ndarray, reach: float) -> np.ndarray:
    """The polyline with its first and last segments carried on by ``reach`` mm (a die's
    end segments run to infinity)."""
    t0 = poly[1] - poly[0]
    t1 = poly[-1] - poly[-2]
    t0, t1 = t0 / np.linalg.norm(t0), t1 / np.linalg.norm(t1)
    return np.vstack([poly[0] - reach * t0, poly, poly[-1] + reach * t1])


def die_outlines(scene, t: float, reach_mm: float | None = None) -> dict[str, np.ndarray]:
    """Each die's surface at time t in the workpiece's frame (mm): the rounded profile
    (:func:`jaxform.dies.sample_rounded`) shifted down by the die's travel at t, its end
    segments carried on by ``reach_mm`` (default: the initial workpiece's size) so that
    a figure shows the die across the part.  Keys: the die names (top, bottom, side)."""
    die = scene.inputs.die
    if die is None:
        return {}
    coords = np.asarray(scene.inputs.coords)
    reach = float(np.ptp(coords, axis=0).max()) if reach_mm is None else reach_mm
    return {
        name: _extended(
            sample_rounded(d.points, d.corner_radius) - np.array([0.0, d.travel_at(t)]), reach
        )
        for name, d in zip(die.names, die.members)
    }


def arc_position(poly: np.ndarray, points: np.ndarray, start: float = 0.0):
    """(s, distance) of each point (n, 2) against the polyline ``poly`` (k, 2): the arc
    length (mm) of its closest point on the polyline, counted from ``start`` at the first
    vertex, and its distance (mm) from it.  Along a vertical wall s runs with z where r
    stands still."""
    a, b = poly[:-1], poly[1:]
    length = np.linalg.norm(b - a, axis=1)
    s0 = start + np.r_[0.0, np.cumsum(length)[:-1]]
    k, u, dist = nearest_on_segments(points, a, b)
    return s0[k] + u * length[k], dist


def contact_profile(
    scene, x: np.ndarray, slip_mm: np.ndarray, status: np.ndarray, t: float | None = None
) -> dict:
    """Per candidate node: position, pressure and shear traction (MPa), status,
    accumulated slip (mm); with the time t also ``s_mm``, the arc length along the die
    the node faces (the nearest die at t, or the candidate's own where candidates are
    (node, die) pairs; from its profile's first point; negative on the extension before
    it) and ``die``, that die's name: the axis a profile is drawn
    against (a vertical die wall has one r but spreads along s)."""
    idx = scene.idx
    pos = positions(scene, x)[np.asarray(idx.contact_nodes)]
    lay = scene.model.layout
    lam = np.asarray(lay.node_multipliers(np.asarray(x)))
    # the contact area of a node: its shape function integrated over the facets in
    # contact (both ends touching); a facet of the free side below an edge node carries
    # no traction, and counting it made a uniform pressure read low at the edge
    facets = np.asarray(idx.contact_facets)
    counted = np.asarray(facets_in_contact(np.asarray(status) > 0, facets))
    area = tributary_areas(pos, facets, scene.model.formulation.axisymmetric, counted)
    safe = np.where(area > 0, area, 1.0)
    along = {}
    if t is not None and scene.inputs.die is not None:
        reach = float(np.ptp(np.asarray(scene.inputs.coords), axis=0).max())
        outlines = die_outlines(scene, t, reach)
        names = list(outlines)
        fits = [arc_position(p, pos, -reach) for p in outlines.values()]
        nearest = np.argmin(np.stack([f[1] for f in fits]), axis=0)
        if scene.model.contact.pairing.copies(len(names)) > 1:  # (node, die) pairs
            nearest = np.asarray(idx.contact_die)
        s_mm = np.stack([f[0] for f in fits])[nearest, np.arange(len(pos))]
        along = dict(s_mm=s_mm, die=np.array([names[k] for k in nearest]))
    return dict(
        **along,
        r_mm=pos[:, 0],
        z_mm=pos[:, 1],
        pressure_MPa=lam[:, 0] / safe,
        shear_MPa=lam[:, 1] / safe,
        status=np.asarray(status),
        slip_mm=np.asarray(slip_mm),
        area_mm2=area,
    )


def zigzag(profile: dict, key: str = "shear_MPa") -> float:
    """Node-to-node oscillation of a contact traction (MPa): the largest |t_i - (t_(i-1) +
    t_(i+1))/2| over the nodes in contact, leaving out the two at the ends of the contact
    zone (an edge carries the corner's stress concentration). A smooth profile scores
    O(h^2 t''), a jump of J between two nodes J/2, an alternation of +-a about a smooth
    profile 2a."""
    order = np.argsort(profile["r_mm"])
    on = np.asarray(profile["status"])[order] > 0
    t = np.asarray(profile[key])[order][on][1:-1]
    if len(t) < 3:
        return 0.0
    return float(np.abs(t[1:-1] - 0.5 * (t[:-2] + t[2:])).max())


def patch_average(values: np.ndarray, elements: np.ndarray) -> np.ndarray:
    """Nodal values smoothed over their element patch: the mean over the elements around
    each node of the element means of the nodal values."""
    el_mean = values[elements].mean(axis=1)
    total = np.zeros(len(values))
    count = np.zeros(len(values))
    np.add.at(total, elements, el_mean[:, None])
    np.add.at(count, elements, 1.0)
    return total / np.maximum(count, 1.0)


def pressure_oscillation(scene, x: np.ndarray) -> float:
    """RMS of (nodal pressure - its patch average) over the RMS nodal pressure (q1q1).

    A checkerboard mode (+1/-1 on alternate nodes) has element means of 0, so it counts in
    full (measure ~1 when it dominates); a smooth field differs from its patch average
    by O(h^2) inside and O(h) on the boundary, so its measure is small."""
    _, p, _ = nodal_fields(scene, x)
    if p is None:
        raise ValueError("pressure_oscillation needs nodal pressures (mesh.element = 'q1q1')")
    dev = p - patch_average(p, np.asarray(scene.mesh.elements))
    return float(np.sqrt(np.mean(dev**2)) / max(np.sqrt(np.mean(p**2)), 1e-300))
