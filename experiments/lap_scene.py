"""A real lap: a boss on a disk upset by a sticking flat die folds over onto the shoulder.

The preform (axisymmetric, mid-plane symmetric, the upper half modelled): a disk of
radius ``--disk-radius`` and half thickness ``--disk-half`` carrying a central boss of
radius ``--boss-radius`` and height ``--boss-height`` on its face.  A flat top die with
sticking friction comes down on the boss.  The boss barrels: its top sticks to the die,
its side bulges out over the disk's free shoulder and folds down onto it, closing the
concave corner between the boss's side and the shoulder: a fold-over lap at the boss's
root, the lap a forging engineer knows from a boss too tall or too voluminous for its
root (the remedy: a larger root fillet, ``--fillet``, or less volume in the boss).  The
section is written as a gmsh mesh (``mesh.file``) with the free surface in the set
``side`` (the boss's side, the root, the shoulder, the rim); the config beside it.

    python experiments/lap_scene.py run --out out/lap            # 0.25 mm, 0.5 s steps
    python experiments/lap_scene.py refine --levels 0,1,2 --out out/lap_refine
    python experiments/lap_scene.py table --at 1.6 out/lap_refine/size_*/flow_lines.npz

``run`` runs the scene once (element size ``--size``, step ``--dt``) and prints its row:
the lap (``jaxform.laps.laps``), the flow lines' fold (``flowlines.self_folds``), the
largest turn of a grid line; it draws ``flow_lines.png`` (with the die) and
``flow_lines_root.png`` (the root: the fold's red cross, the lap's green circle) and saves
every row's lines and history in ``flow_lines.npz``.  ``refine`` runs the LEVELS (element
size and step each divided by sqrt 2 twice) and writes ``refine.csv``; ``table`` reads
saved runs at one stroke (a run's rows up to a stroke are the run to that stroke).

With the square root (the default) the lap forms, but the stroke at which its crease
closes depends on the mesh (a re-entrant corner is singular), and jaxform has no
self-contact: past the closing the two faces pass through each other.  With a fillet
(``--fillet 0.4``) the root folds over more slowly (docs/outputs.md).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from jaxform import mesh as meshing


def square_root_section(disk_radius, disk_half, boss_radius, boss_height, size) -> meshing.Mesh:
    """The structured quad mesh (element size about ``size`` mm) of the section
    [0, R] x [0, h] plus [0, a] x [h, h + b] with sets symmetry (z = 0), axis (r = 0),
    top (the boss's top) and side (the boss's side, the shoulder z = h, the rim r = R)."""
    R, h, a, b = disk_radius, disk_half, boss_radius, boss_height
    na = max(int(round(a / size)), 1)
    nR = na + max(int(round((R - a) / size)), 1)
    nh = max(int(round(h / size)), 1)
    nb = max(int(round(b / size)), 1)
    r = np.concatenate([np.linspace(0.0, a, na + 1), np.linspace(a, R, nR - na + 1)[1:]])
    z = np.concatenate([np.linspace(0.0, h, nh + 1), np.linspace(h, h + b, nb + 1)[1:]])
    full = meshing.tensor_grid(r, z)
    c = full.coords
    centre = c[full.elements].mean(axis=1)
    keep = (centre[:, 1] < h) | (centre[:, 0] < a)
    elements = full.elements[keep]
    used = np.unique(elements)
    renum = -np.ones(len(c), dtype=np.int64)
    renum[used] = np.arange(len(used))
    coords, elements = c[used], renum[elements]
    tol = 1e-9 * max(R, h + b)
    # the boundary facets: element edges used by one element
    edges = np.concatenate([elements[:, [k, (k + 1) % 4]] for k in range(4)])
    key = np.sort(edges, axis=1)
    _, inv, count = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    facets = edges[count[inv.ravel()] == 1]
    mid = coords[facets].mean(axis=1)
    groups = {
        "symmetry": np.abs(mid[:, 1]) < tol,
        "axis": np.abs(mid[:, 0]) < tol,
        "top": np.abs(mid[:, 1] - (h + b)) < tol,
    }
    groups["side"] = ~(groups["symmetry"] | groups["axis"] | groups["top"])
    facet_sets = {k: facets[v] for k, v in groups.items()}
    node_sets = {k: np.unique(v) for k, v in facet_sets.items()}
    return meshing.Mesh(coords, elements, node_sets, facet_sets)


def stepped_section(args) -> meshing.Mesh:
    """The quad mesh (gmsh, element size ``args.size`` mm) of the section [0, R] x [0, h]
    plus [0, a] x [h, h + b] with a fillet of radius ``args.fillet`` at the boss's root
    (0: the structured mesh of :func:`square_root_section`, the root a square corner),
    with sets symmetry (z = 0), axis (r = 0), top (the boss's top) and side (the rim
    r = R, the shoulder z = h, the fillet, the boss's side)."""
    R, h, a, b, rho = (args.disk_radius, args.disk_half, args.boss_radius, args.boss_height,
                       args.fillet)  # fmt: skip
    if rho == 0.0:
        return square_root_section(R, h, a, b, args.size)
    n = max(int(np.ceil(0.5 * np.pi * rho / (0.5 * args.size))), 2) if rho > 0.0 else 0
    theta = np.linspace(1.5 * np.pi, np.pi, n + 1)  # clockwise round the fillet's centre
    arc = np.column_stack([a + rho + rho * np.cos(theta), h + rho + rho * np.sin(theta)])
    root = arc if n else np.array([[a, h]])  # the fillet (half the element size apart)
    points = np.vstack([[[0.0, 0.0], [R, 0.0], [R, h]], root, [[a, h + b], [0.0, h + b]]])
    labels = ["symmetry"] + ["side"] * (len(points) - 3) + ["top", "axis"]
    sizes = np.full(len(points), args.size)
    sizes[3 : 3 + len(root)] = 0.5 * args.size if n else args.size
    return meshing.polygon_quads(points, labels, sizes)


CONFIG = """\
# A boss on a disk upset by a sticking flat die (experiments/lap_scene.py writes this
# config and its mesh): the boss's side folds over onto the disk's shoulder, a lap.
[billet]
diameter_mm = {diameter}
height_mm = {height}

[mesh]
file = "{mesh}"
element = "q1p0"

[remesh]
quality_below = 0.3
element_size_mm = {size}

[material]
preset = "al1100_673K"

[die]
speed_mm_s = 0.1
reduction = {reduction}

[friction]
model = "sticking"

[time]
dt_s = {dt}

[solver]
max_cutbacks = 8

[output]
flow_line_spacing_mm = {spacing}
"""


def write_scene(out: Path, args) -> Path:
    """The mesh (``section.msh``) and config (``config.toml``) of the scene in ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    mesh = stepped_section(args)
    meshing.write_mesh(out / "section.msh", mesh)
    height = 2.0 * (args.disk_half + args.boss_height)
    text = CONFIG.format(diameter=2.0 * args.disk_radius, height=height,
                         mesh=(out / "section.msh").resolve(), size=args.size,
                         reduction=2.0 * args.travel / height, dt=args.dt,
                         spacing=args.spacing)  # fmt: skip
    (out / "config.toml").write_text(text)
    return out / "config.toml"


def analyse(result, spacing: float, lap_angle: float):
    """(laps, folds, turns): the run's laps (``jaxform.laps.laps``), the flow lines' folds
    at the last row (``flowlines.self_folds``) and the largest turn of any line (deg) at
    every row."""
    from jaxform.flowlines import flow_lines, largest_turn, self_folds
    from jaxform.laps import laps

    lines = flow_lines(result, spacing)
    rows = len(result.history["time_s"])
    turns = np.array([largest_turn(lines, spacing, k) for k in range(rows)])
    return laps(result.history, lap_angle), self_folds(lines, spacing), turns, lines


LEVELS = ((0.25, 0.5), (0.177, 0.35), (0.125, 0.25))  # (element size mm, step s)


def run_level(args, size: float, dt: float) -> dict:
    """Run the scene at one element size and step; its row of the refinement table, and
    the figures of the flow lines (whole section with the die; the root of the lap)."""
    import time

    import jaxform
    from jaxform import plot
    from jaxform.flowlines import line_fold
    from jaxform.postprocess import die_outlines, positions

    level = argparse.Namespace(**{**vars(args), "size": size, "dt": dt})
    out = args.out / f"size_{size:g}"
    cfg = write_scene(out, level)
    t0 = time.perf_counter()
    res = jaxform.run(str(cfg), ["output.plots=false", "output.fields=false"])
    wall = time.perf_counter() - t0
    lap_list, folds, turns, lines = analyse(res, args.spacing, 10.0)
    h = res.history
    sc = res.final_scene
    pos, el = positions(sc, res.fields["x"][-1]), np.asarray(sc.mesh.elements)
    frame = plot.SectionFrame(("r [mm]", "z [mm]"), die_outlines(sc, float(h["time_s"][-1])))
    title = f"flow lines, stroke {h['stroke_mm'][-1]:.3g} mm, elements {size:g} mm"
    plot.flow_lines(pos, el, lines.polylines(-1), out / "flow_lines.png", title, frame)
    fig = plot.flow_lines(pos, el, lines.polylines(-1), out / "flow_lines_root.png",
                          "the lap's root: surface line folded onto itself", frame)  # fmt: skip
    ax = fig.axes[0]
    for f in folds:
        ax.plot([f.r_mm], [f.z_mm], "x", color="tab:red", ms=12, mew=2, zorder=6)
    for lap in lap_list:
        ax.plot([lap["r_mm"]], [lap["z_mm"]], "o", mfc="none", color="tab:green", ms=14, zorder=6)
    ax.set_xlim(2.2, 3.6)
    ax.set_ylim(0.9, 1.9)
    fig.savefig(out / "flow_lines_root.png", dpi=120)
    first = int(np.argmax(turns >= 150.0)) if np.any(turns >= 150.0) else -1
    row = dict(size_mm=size, dt_s=dt, steps=len(h["time_s"]) - 1, remeshes=len(res.remeshes),
               wall_s=round(wall, 1), stroke_mm=float(h["stroke_mm"][-1]),
               force_N=float(h["force_N"][-1]), end_wedge_deg=float(h["wedge_angle_deg"][-1]),
               laps=len(lap_list), pockets=len(res.pockets))  # fmt: skip
    if lap_list:
        lap = lap_list[0]
        row.update(lap_stroke_mm=lap["stroke_mm"], lap_r_mm=lap["r_mm"], lap_z_mm=lap["z_mm"],
                   lap_end_r_mm=lap["end_r_mm"], lap_end_z_mm=lap["end_z_mm"],
                   lap_depth_mm=lap["depth_mm"])  # fmt: skip
    # the stroke where the air wedge would close: the wedge angle's line through its last
    # two rows reaching 0
    a, s = h["wedge_angle_deg"][-2:], h["stroke_mm"][-2:]
    row["closing_stroke_mm"] = float(s[1] - a[1] * (s[1] - s[0]) / (a[1] - a[0]))
    row["fold_turn_stroke_mm"] = float(h["stroke_mm"][first]) if first >= 0 else float("nan")
    if folds:
        f = folds[0]
        row.update(fold_turn_deg=f.turn_deg, fold_r_mm=f.r_mm, fold_z_mm=f.z_mm,
                   fold_family=f.family, fold_depth_mm=f.depth_mm)  # fmt: skip
    row["grid_line_turn_deg"] = max(
        (line_fold(p, args.spacing)[0] for k, p in enumerate(lines.polylines(-1))
         if lines.family[k] < 2), default=0.0)  # fmt: skip
    np.savez(out / "flow_lines.npz", points=lines.points, line=lines.line,
             family=lines.family, level=lines.level, turn_deg=turns,
             **{k: np.asarray(v) for k, v in h.items()})  # fmt: skip
    print(row, flush=True)
    return row


def at_stroke(path: Path, spacing: float, stroke: float | None) -> dict:
    """A run's lap and flow-line fold at its first row at or past ``stroke`` (mm; None:
    its last row), from its ``flow_lines.npz``: the run to that stroke is the run's rows
    up to there (laps() of that history, self_folds() of the lines at that row)."""
    from jaxform.flowlines import FlowLines, line_fold, self_folds
    from jaxform.laps import laps

    z = np.load(path, allow_pickle=True)
    s = z["stroke_mm"]
    k = len(s) - 1 if stroke is None else int(np.argmax(s >= stroke - 1e-9))
    names = ("time_s", "stroke_mm", "wedge_angle_deg", "wedge_r_mm", "wedge_z_mm",
             "wedge_depth_mm")  # fmt: skip
    hist = {n: z[n][: k + 1] for n in names}
    lines = FlowLines(z["points"][: k + 1], z["line"], z["family"], z["level"])
    out = dict(row=k, stroke_mm=float(s[k]), wedge_angle_deg=float(z["wedge_angle_deg"][k]),
               laps=laps(hist, 10.0), folds=self_folds(lines, spacing))  # fmt: skip
    out["grid_turn_deg"] = max(line_fold(p, spacing)[0] for j, p in enumerate(lines.polylines())
                               if lines.family[j] < 2)  # fmt: skip
    return out


def main_args(argv=None) -> argparse.Namespace:
    """The command line's arguments (the scene's dimensions, mesh, step, output)."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("what", choices=("write", "run", "refine", "table"))
    p.add_argument("--disk-radius", type=float, default=5.0)
    p.add_argument("--disk-half", type=float, default=1.5)
    p.add_argument("--boss-radius", type=float, default=2.5)
    p.add_argument("--boss-height", type=float, default=2.5)
    p.add_argument("--fillet", type=float, default=0.0, help="the boss's root radius (mm)")
    p.add_argument("--travel", type=float, default=0.82, help="the die's travel (mm)")
    p.add_argument("--size", type=float, default=0.25, help="element size (mm)")
    p.add_argument("--dt", type=float, default=0.5, help="step (s)")
    p.add_argument("--spacing", type=float, default=0.5, help="flow lines' spacing (mm)")
    p.add_argument("--levels", default="0,1,2", help="refine: which of LEVELS to run")
    p.add_argument("--out", type=Path, default=Path("out/lap"))
    p.add_argument("--at", type=float, default=None, help="table: the stroke (mm) to read")
    p.add_argument("runs", nargs="*", type=Path, help="table: the runs' flow_lines.npz")
    return p.parse_intermixed_args(argv)


def main(argv=None):
    args = main_args(argv)
    if args.what == "write":
        print(write_scene(args.out, args))
        return
    import jaxform
    from jaxform.io import write_csv

    if args.what == "table":
        for path in args.runs:
            print(path, at_stroke(path, args.spacing, args.at))
        return
    jaxform.enable_x64()
    if args.what == "run":
        run_level(args, args.size, args.dt)
        return
    rows = [run_level(args, *LEVELS[int(k)]) for k in args.levels.split(",")]
    keys = list(dict.fromkeys(k for r in rows for k in r))
    write_csv(
        args.out / "refine.csv", {k: np.array([r.get(k, np.nan) for r in rows]) for k in keys}
    )


if __name__ == "__main__":
    main()
