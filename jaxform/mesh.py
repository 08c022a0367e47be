"""Quadrilateral meshes of 2-D sections (set-up code: NumPy, outside jit).

Coordinates are (r, z) for axisymmetric sections and (x, y) for plane strain, in mm.
Elements are 4-node quadrilaterals, nodes counter-clockwise.  Named node sets and facet
sets (pairs of node indices along the boundary) mark where boundary conditions and dies
act.  For a billet's quarter section (r in [0, R], z in [0, H/2]):

* ``axis``      nodes on r = 0 (u_r = 0)
* ``symmetry``  nodes on the mid-plane z = 0 (u_z = 0)
* ``top``       nodes on the die face z = H/2
* ``side``      nodes on the lateral free surface
* ``free_surface`` top and side together: every node a die may touch
"""

from __future__ import annotations

import contextlib
import io
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from jaxform.geometry import min_quality, polygon_measure


@dataclass(frozen=True)
class Mesh:
    coords: np.ndarray  # (n_nodes, 2) float64, mm
    elements: np.ndarray  # (n_elements, 4) int, counter-clockwise
    node_sets: dict[str, np.ndarray] = field(default_factory=dict)
    facet_sets: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def n_nodes(self) -> int:
        return self.coords.shape[0]

    @property
    def n_elements(self) -> int:
        return self.elements.shape[0]


class MeshError(ValueError):
    pass


def _structured(xs: np.ndarray, ys: np.ndarray):
    """Nodes of an (nx+1) x (ny+1) logical grid and its quads; node id = j*(nx+1) + i."""
    nx, ny = xs.shape[1] - 1, xs.shape[0] - 1
    coords = np.column_stack([xs.ravel(), ys.ravel()])
    i, j = np.meshgrid(np.arange(nx), np.arange(ny))
    n0 = (j * (nx + 1) + i).ravel()
    elements = np.column_stack([n0, n0 + 1, n0 + nx + 2, n0 + nx + 1])
    return coords, elements.astype(np.int64)


def _grid_sets(nx: int, ny: int):
    ids = np.arange((nx + 1) * (ny + 1)).reshape(ny + 1, nx + 1)
    nodes = {"left": ids[:, 0], "right": ids[:, -1], "bottom": ids[0, :], "top": ids[-1, :]}
    facets = {k: np.column_stack([v[:-1], v[1:]]) for k, v in nodes.items()}
    return {k: np.sort(v) for k, v in nodes.items()}, facets


def rectangle(width: float, height: float, nx: int, ny: int, origin=(0.0, 0.0)) -> Mesh:
    """Structured nx x ny mesh of [x0, x0+width] x [y0, y0+height] with sets left, right,
    bottom, top."""
    if nx < 1 or ny < 1:
        raise MeshError(f"mesh size {nx} x {ny}: both counts must be >= 1")
    if width <= 0 or height <= 0:
        raise MeshError(f"rectangle {width} x {height} mm: both sides must be > 0")
    x = origin[0] + np.linspace(0.0, width, nx + 1)
    y = origin[1] + np.linspace(0.0, height, ny + 1)
    return tensor_grid(x, y)


def tensor_grid(x: np.ndarray, y: np.ndarray) -> Mesh:
    """Mesh of the tensor grid of increasing node coordinates x (nx+1,) and y (ny+1,),
    with sets left/right/bottom/top."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    if x.size < 2 or y.size < 2 or np.any(np.diff(x) <= 0) or np.any(np.diff(y) <= 0):
        raise MeshError("tensor grid: node coordinates must increase, at least 2 per direction")
    xs, ys = np.meshgrid(x, y)
    coords, elements = _structured(xs, ys)
    nodes, facets = _grid_sets(x.size - 1, y.size - 1)
    return Mesh(coords, elements, nodes, facets)


def mapped_quad(corners, nx: int, ny: int) -> Mesh:
    """Structured nx x ny mesh of the quadrilateral with ``corners`` (4, 2), counter-clockwise,
    by the bilinear map of the unit square (a Coons patch with straight edges).

    Edges and their sets: ``bottom`` corner 0 -> 1, ``right`` 1 -> 2, ``top`` 2 -> 3,
    ``left`` 3 -> 0 (logical directions: nx elements along bottom/top, ny along left/right).
    Cook's membrane: corners (0, 0), (48, 44), (48, 60), (0, 44) mm.
    """
    c = np.asarray(corners, dtype=float)
    if c.shape != (4, 2) or not np.all(np.isfinite(c)):
        raise MeshError(f"quadrilateral corners: need 4 finite [x, y] points, got shape {c.shape}")
    if nx < 1 or ny < 1:
        raise MeshError(f"mesh size {nx} x {ny}: both counts must be >= 1")
    # convex and counter-clockwise: every turn is to the left
    d = np.roll(c, -1, axis=0) - c
    turns = d[:, 0] * np.roll(d, -1, axis=0)[:, 1] - d[:, 1] * np.roll(d, -1, axis=0)[:, 0]
    if np.any(turns <= 0):
        raise MeshError("quadrilateral corners: must be convex and counter-clockwise")
    s, t = np.meshgrid(np.linspace(0.0, 1.0, nx + 1), np.linspace(0.0, 1.0, ny + 1))
    s, t = s[..., None], t[..., None]
    pts = (1 - s) * (1 - t) * c[0] + s * (1 - t) * c[1] + s * t * c[2] + (1 - s) * t * c[3]
    coords, elements = _structured(pts[..., 0], pts[..., 1])
    nodes, facets = _grid_sets(nx, ny)
    return Mesh(coords, elements, nodes, facets)


def graded_nodes(length: float, fine_length: float, n_fine: int, growth: float) -> np.ndarray:
    """Node coordinates on [0, length]: n_fine equal elements on [0, fine_length], then
    elements that grow geometrically by about ``growth`` (> 1) each up to ``length``.

    The ratio is adjusted so that the last node lands on ``length`` exactly and the first
    coarse element is no smaller than the fine ones."""
    if not (0 < fine_length <= length) or n_fine < 1:
        raise MeshError(
            f"graded nodes: need 0 < fine length {fine_length} <= length {length} and n_fine >= 1"
        )
    fine = np.linspace(0.0, fine_length, n_fine + 1)
    rest = length - fine_length
    h = fine_length / n_fine
    if rest <= 1e-12 * length:
        return fine
    if growth <= 1.0:
        raise MeshError(f"graded nodes: growth {growth} must be > 1")
    # fewest elements with sizes h q^k (k = 1..n, q <= growth) that cover the rest
    n = 1
    while h * sum(growth**k for k in range(1, n + 1)) < rest:
        n += 1
    lo, hi = 1.0, growth  # the ratio q that fits exactly: sum_k h q^k = rest (bisection)
    if h * n >= rest:  # n equal elements of size >= h already too long: make them equal
        sizes = np.full(n, rest / n)
    else:
        for _ in range(200):
            q = 0.5 * (lo + hi)
            if h * np.sum(q ** np.arange(1, n + 1)) < rest:
                lo = q
            else:
                hi = q
        sizes = h * q ** np.arange(1, n + 1)
        sizes *= rest / sizes.sum()
    return np.concatenate([fine, fine_length + np.cumsum(sizes)])


def block(
    width: float,
    depth: float,
    fine_width: float,
    fine_depth: float,
    nx: int,
    ny: int,
    growth: float,
) -> Mesh:
    """Plane-strain block [0, width] x [0, depth] for indentation from the top, symmetric
    about x = 0: nx x ny equal elements in the corner zone [0, fine_width] x
    [depth - fine_depth, depth] under the punch, growing geometrically outside it.

    Sets: ``axis`` (x = 0, the symmetry line), ``base`` (y = 0), ``top`` (y = depth),
    ``side`` (x = width), ``free_surface`` (top and side)."""
    x = graded_nodes(width, fine_width, nx, growth)
    y = depth - graded_nodes(depth, fine_depth, ny, growth)[::-1]
    mesh = tensor_grid(x, y)
    n, f = mesh.node_sets, mesh.facet_sets
    nodes = {
        "axis": n["left"],
        "base": n["bottom"],
        "top": n["top"],
        "side": n["right"],
        "free_surface": np.union1d(n["top"], n["right"]),
    }
    facets = {"axis": f["left"], "base": f["bottom"], "top": f["top"], "side": f["right"]}
    return Mesh(mesh.coords, mesh.elements, nodes, facets)


def billet_quarter(
    radius: float,
    half_height: float,
    nr: int,
    nz: int,
    profile: Callable[[np.ndarray], np.ndarray] | None = None,
) -> Mesh:
    """Quarter r-z section of a billet; ``profile(z)`` gives the outer radius at height z (mm).

    Without a profile the section is the rectangle [0, radius] x [0, half_height]; with
    one the nodes of each row are spread evenly from the axis to profile(z) (a preform).
    """
    mesh = rectangle(radius, half_height, nr, nz)
    coords = mesh.coords.copy()
    if profile is not None:
        z = coords[:, 1]
        outer = np.asarray(profile(z), dtype=float)
        if np.any(~np.isfinite(outer)) or np.any(outer <= 0):
            raise MeshError("billet profile: the outer radius must be finite and > 0 at every z")
        coords[:, 0] = coords[:, 0] / radius * outer
    n = mesh.node_sets
    nodes = {
        "axis": n["left"],
        "symmetry": n["bottom"],
        "top": n["top"],
        "side": n["right"],
        "free_surface": np.union1d(n["top"], n["right"]),
    }
    f = mesh.facet_sets
    facets = {"axis": f["left"], "symmetry": f["bottom"], "top": f["top"], "side": f["right"]}
    return Mesh(coords, mesh.elements, nodes, facets)


def check_sheet(elements: np.ndarray) -> None:
    """Raise MeshError unless the counter-clockwise quads form one sheet: no element
    walks an edge that another walks the same way (two elements on the same side of it:
    they overlap), and the boundary is one loop that does not touch itself."""
    edges = _element_edges(elements)
    if len(np.unique(edges, axis=0)) != len(edges):
        raise MeshError("overlapping elements (an edge walked twice the same way)")
    boundary_loop(elements)


def _element_edges(elements: np.ndarray) -> np.ndarray:
    """(4 n_el, 2) the edges each counter-clockwise quad walks, in its order."""
    e = np.asarray(elements, dtype=np.int64)
    return np.stack([e, np.roll(e, -1, axis=1)], axis=-1).reshape(-1, 2)


def boundary_edges(elements: np.ndarray) -> np.ndarray:
    """(n_b, 2) directed boundary edges of a mesh of counter-clockwise quads (the material
    on their left)."""
    edges = _element_edges(elements)
    n = int(edges.max()) + 1 if edges.size else 1
    # an edge is on the boundary when no element walks it the other way
    inner = np.isin(edges[:, 1] * n + edges[:, 0], edges[:, 0] * n + edges[:, 1])
    return edges[~inner]


def boundary_loop(elements: np.ndarray) -> np.ndarray:
    """The boundary nodes of a mesh of counter-clockwise quads as one counter-clockwise
    loop (each once).  Raises MeshError where the boundary touches itself at a node or
    is not one closed loop."""
    edges = boundary_edges(elements)
    nxt = dict(zip(edges[:, 0].tolist(), edges[:, 1].tolist()))
    if len(nxt) != len(edges):
        raise MeshError("the section's boundary touches itself at a node")
    start = int(edges[0, 0])
    loop = [start]
    while (a := nxt[loop[-1]]) != start:
        loop.append(a)
        if len(loop) > len(edges):
            break
    if len(loop) != len(edges):
        raise MeshError("the section's boundary is not one closed loop (a hole?)")
    return np.asarray(loop)


# where two sets meet on an edge's nodes, the edge takes the first that has it: held
# boundaries before free ones
_SET_ORDER = (
    "axis",
    "symmetry",
    "base",
    "clamped",
    "top",
    "bottom",
    "inner",
    "outer",
    "side",
    "loaded",
)


def boundary_polygon(mesh, pos: np.ndarray):
    """(points (n, 2), labels (n,), nodes (n,)): the boundary of the mesh at positions
    ``pos`` as one counter-clockwise loop, ``labels[i]`` the set of the edge from node
    ``nodes[i]`` to the next ("" where no set has it).  Raises MeshError for a section
    whose boundary is not one loop."""
    loop = boundary_loop(mesh.elements)
    n = mesh.n_nodes
    keys = {}
    for name in sorted(mesh.facet_sets, key=lambda s: _SET_ORDER.index(s)
                       if s in _SET_ORDER else len(_SET_ORDER)):  # fmt: skip
        f = np.asarray(mesh.facet_sets[name], dtype=np.int64).reshape(-1, 2)
        for a, b in f.tolist():
            keys.setdefault(min(a, b) * n + max(a, b), name)
    after = np.roll(loop, -1)
    labels = [keys.get(min(a, b) * n + max(a, b), "") for a, b in zip(loop, after)]
    return pos[loop], labels, loop


def element_areas(coords: np.ndarray, elements: np.ndarray) -> np.ndarray:
    """Signed areas (shoelace); positive for counter-clockwise quads."""
    return polygon_measure(coords[elements], axisymmetric=False)


def _named_cells(m, cell_type: str, dim: int) -> dict[str, np.ndarray]:
    """Named groups of ``cell_type`` cells (gmsh dimension ``dim``): gmsh physical groups
    ($PhysicalNames + the 'gmsh:physical' tags, any gmsh version) or meshio cell sets
    (other formats)."""
    groups: dict[str, list] = {}
    blocks = {i: np.asarray(c.data) for i, c in enumerate(m.cells) if c.type == cell_type}
    tags = m.cell_data.get("gmsh:physical")
    if tags is not None:
        names = {int(v[0]): k for k, v in (m.field_data or {}).items() if int(v[1]) == dim}
        for i, block in blocks.items():
            t = np.asarray(tags[i])
            for tag, name in names.items():
                if np.any(t == tag):
                    groups.setdefault(name, []).append(block[t == tag])
    for name, per_block in (m.cell_sets or {}).items():
        if name.startswith("gmsh:") or name in groups:
            continue
        for i, sel in enumerate(per_block):
            if i in blocks and sel is not None and len(sel):
                groups.setdefault(name, []).append(blocks[i][np.asarray(sel, dtype=np.int64)])
    return {k: np.concatenate(v).astype(np.int64) for k, v in groups.items()}


def read_mesh(path: str | Path, tolerance: float = 1e-9) -> Mesh:
    """Read a 2-D quadrilateral mesh through meshio (gmsh .msh, .vtu, ...).

    Physical groups / cell sets of line cells become facet and node sets by name, those
    of vertex cells node sets only (e.g. one node of a full-width section whose u_x is
    fixed, ``axis``, to remove the rigid-body mode); the quads are re-oriented
    counter-clockwise; the z (third) coordinate must be 0.
    """
    import meshio

    # meshio's readers fail on garbage with these, and when no reader fits it prints to
    # stdout and calls sys.exit(1): one MeshError naming the cause instead
    try:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            m = meshio.read(str(path))
    except (meshio.ReadError, ValueError, KeyError, IndexError, UnicodeDecodeError) as err:
        raise MeshError(f"not a mesh meshio can read ({type(err).__name__}: {err})") from None
    except SystemExit:
        raise MeshError("not a mesh meshio can read (no reader for its format)") from None
    pts = np.asarray(m.points, dtype=float)
    if pts.shape[1] == 3:
        if np.max(np.abs(pts[:, 2])) > tolerance:
            raise MeshError(f"{path}: points have nonzero z; a 2-D section is expected")
        pts = pts[:, :2]
    quads = [c.data for c in m.cells if c.type == "quad"]
    if not quads:
        raise MeshError(f"{path}: no 'quad' cells (only 4-node quadrilaterals are supported)")
    elements = np.concatenate(quads).astype(np.int64)
    # keep only the nodes that quads use, renumbered
    used = np.unique(elements)
    renum = -np.ones(pts.shape[0], dtype=np.int64)
    renum[used] = np.arange(used.size)
    coords = pts[used]
    elements = renum[elements]
    flip = element_areas(coords, elements) < 0
    elements[flip] = elements[flip][:, ::-1]
    facet_sets: dict[str, np.ndarray] = {}
    node_sets: dict[str, np.ndarray] = {}
    for name, seg in _named_cells(m, "line", 1).items():
        seg = renum[seg]
        if np.any(seg < 0):
            raise MeshError(f"{path}: set {name!r} has nodes that belong to no quad")
        facet_sets[name] = seg
        node_sets[name] = np.unique(seg)
    for name, pts_ in _named_cells(m, "vertex", 0).items():
        if name in node_sets:
            raise MeshError(f"{path}: set {name!r} is both a line and a point group")
        nodes = renum[pts_.ravel()]
        if np.any(nodes < 0):
            raise MeshError(f"{path}: point set {name!r} has nodes that belong to no quad")
        node_sets[name] = np.unique(nodes)
    return Mesh(coords, elements, node_sets, facet_sets)


def write_mesh(path: str | Path, mesh: Mesh) -> None:
    """Write ``mesh`` as gmsh 2.2 (ASCII) through meshio, readable by :func:`read_mesh`:
    each facet set a physical group of line cells, each node set without a facet set of
    the same name a physical group of vertex cells, the quads one group ``domain``."""
    import meshio

    lines = {k: np.asarray(v, dtype=np.int64) for k, v in mesh.facet_sets.items()}
    points = {k: np.asarray(v, dtype=np.int64) for k, v in mesh.node_sets.items() if k not in lines}
    cells, tags, field_data = [], [], {}
    for tag, (name, data) in enumerate([*lines.items(), *points.items()], start=1):
        cell, dim = ("line", 1) if name in lines else ("vertex", 0)
        cells.append((cell, data.reshape(-1, dim + 1)))
        tags.append(np.full(len(cells[-1][1]), tag))
        field_data[name] = np.array([tag, dim])
    tag = len(cells) + 1
    cells.append(("quad", np.asarray(mesh.elements, dtype=np.int64)))
    tags.append(np.full(len(mesh.elements), tag))
    field_data["domain"] = np.array([tag, 2])
    pts = np.column_stack([mesh.coords, np.zeros(len(mesh.coords))])
    meshio.write(
        str(path),
        meshio.Mesh(
            pts,
            cells,
            field_data=field_data,
            cell_data={"gmsh:physical": tags, "gmsh:geometrical": tags},
        ),
        file_format="gmsh22",
        binary=False,
    )


# gmsh's 2-D algorithms tried in turn (Frontal-Delaunay, Frontal-Delaunay for quads,
# Delaunay), each recombined by Blossom: the first whose worst corner quality reaches
# QUAD_QUALITY is taken, else the best of them
QUAD_ALGORITHMS = (6, 8, 5)
QUAD_QUALITY = 0.3


def polygon_quads(points, labels, sizes, split: bool = False) -> Mesh:
    """All-quadrilateral mesh of a simple polygon by gmsh (2-D algorithms of
    :data:`QUAD_ALGORITHMS` with Blossom recombination), keeping every polygon vertex as a
    node.

    Arguments:
        points: (n, 2) the polygon's vertices, counter-clockwise (mm).
        labels: n set names, ``labels[i]`` for the edge points[i] -> points[i + 1] ("" for
            none): each name becomes a facet set (and the node set of its nodes).
        sizes: (n,) the element size wanted at each vertex (mm); the interior takes the
            size gmsh spreads from the boundary.

    Each edge is split into round(length / size) segments (at least one), one more on the
    edge whose segments are longest when the total is odd: Blossom recombination gives an
    all-quad mesh for an even number of boundary segments.  An algorithm's mesh that is
    not one sheet (:func:`check_sheet`: gmsh can fold a quad over its neighbours where
    the polygon nearly touches itself) counts as its failure.  Raises MeshError when no
    algorithm gives an all-quad mesh.

    ``split``: mesh at twice the sizes and split every element through its edge midpoints
    and centre (gmsh's subdivision: a triangle into three quadrilaterals, a quadrilateral
    into four), so the mesh is all quadrilaterals whatever triangles the recombination
    leaves (an acute tip of material: a fin a closing pocket leaves along a die, where
    Blossom leaves a triangle at any size), at the price of the split triangles' corners."""
    pts = np.asarray(points, dtype=float)
    sizes = np.asarray(sizes, dtype=float)
    if polygon_measure(pts[None], axisymmetric=False)[0] <= 0.0:
        raise MeshError("polygon_quads: the polygon must be counter-clockwise")
    if split:  # each segment is halved: the sizes before the split are twice the wanted
        sizes = 2.0 * sizes
    length = np.linalg.norm(np.roll(pts, -1, axis=0) - pts, axis=1)
    h_edge = 0.5 * (sizes + np.roll(sizes, -1))
    segments = np.maximum(1, np.round(length / h_edge)).astype(int)
    if segments.sum() % 2 and not split:
        segments[np.argmax(length / segments)] += 1
    best, errors = None, []
    for algorithm in QUAD_ALGORITHMS:
        try:
            mesh = _gmsh_quads(pts, labels, sizes, segments, (algorithm, split))
            check_sheet(mesh.elements)
        except MeshError as err:
            errors.append(f"algorithm {algorithm}: {err}")
            continue
        q = float(min_quality(mesh.coords, mesh.elements))
        if best is None or q > best[0]:
            best = (q, mesh)
        if q >= QUAD_QUALITY:
            break
    if best is None:
        raise MeshError("gmsh gave no all-quad mesh of the section (" + "; ".join(errors) + ")")
    return best[1]


def _gmsh_quads(pts, labels, sizes, segments, how: tuple[int, bool]) -> Mesh:
    """One gmsh run of :func:`polygon_quads`: ``how`` = (the 2-D algorithm, whether every
    element is split into quadrilaterals)."""
    import gmsh

    gmsh.initialize(readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("section")
        geo = gmsh.model.geo
        tags = [geo.addPoint(x, y, 0.0, h) for (x, y), h in zip(pts, sizes)]
        lines = [geo.addLine(tags[i], tags[(i + 1) % len(tags)]) for i in range(len(tags))]
        for line, k in zip(lines, segments):
            geo.mesh.setTransfiniteCurve(line, int(k) + 1)
        geo.addPlaneSurface([geo.addCurveLoop(lines)])
        geo.synchronize()
        options = {"Mesh.RecombineAll": 1, "Mesh.Algorithm": how[0],
                   "Mesh.RecombinationAlgorithm": 1, "Mesh.Smoothing": 3,
                   "Mesh.SubdivisionAlgorithm": int(how[1])}  # fmt: skip
        for name, value in options.items():
            gmsh.option.setNumber(name, value)
        gmsh.model.mesh.generate(2)
        node_tags, xyz, _ = gmsh.model.mesh.getNodes()
        types, _, conn = gmsh.model.mesh.getElements(2)
        edges = [gmsh.model.mesh.getElements(1, line)[2] for line in lines]
    except Exception as err:  # gmsh raises a bare Exception with its last error
        raise MeshError(f"gmsh failed: {err}") from None
    finally:
        gmsh.finalize()
    if [int(t) for t in types] != [3]:
        raise MeshError(f"gmsh left non-quadrilateral elements (types {list(map(int, types))})")
    renum = np.zeros(int(node_tags.max()) + 1, dtype=np.int64)
    renum[node_tags.astype(np.int64)] = np.arange(len(node_tags))
    coords = xyz.reshape(-1, 3)[:, :2].copy()
    coords[renum[tags]] = pts  # the vertices exactly
    elements = renum[conn[0].astype(np.int64)].reshape(-1, 4)
    flip = element_areas(coords, elements) < 0
    elements[flip] = elements[flip][:, ::-1]
    facet_sets: dict[str, list] = {}
    for name, e in zip(labels, edges):
        if name:
            facet_sets.setdefault(name, []).append(renum[e[0].astype(np.int64)].reshape(-1, 2))
    facets = {k: np.concatenate(v) for k, v in facet_sets.items()}
    nodes = {k: np.unique(v) for k, v in facets.items()}
    return Mesh(coords, elements, nodes, facets)
