"""PNG figures, drawn on matplotlib Figures with their own Agg canvas.

No pyplot: importing or calling this module leaves matplotlib's global backend and
figure registry as they were (no display needed, nothing to close).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter

# a field whose spread is below this fraction of its magnitude is round-off: it is drawn
# as the uniform field it is (one colour), not as a pattern of its last bits
UNIFORM_RTOL = 1e-9


DIE_COLOUR = "0.35"  # the dies' outlines: a neutral grey over any colour map


@dataclass(frozen=True)
class SectionFrame:
    """What a section plot draws around its field: the axis labels (with units) and the
    die outlines at that instant in the workpiece's frame ({name: (k, 2) polyline, mm},
    :func:`jaxform.postprocess.die_outlines`).  Section plots take one as ``axes`` (a
    plain pair of labels still works: no dies)."""

    labels: tuple[str, str] = ("r [mm]", "z [mm]")
    dies: dict = field(default_factory=dict)


def _frame(axes) -> SectionFrame:
    return axes if isinstance(axes, SectionFrame) else SectionFrame(tuple(axes))


def _section_axes(ax, frame: SectionFrame, coords, title: str) -> None:
    """Equal-aspect axes over ``coords`` (with a margin that shows the dies touching
    it), the labels, the title, and each die's outline in grey (its line's gid:
    'die:<name>'), clipped by the axes."""
    lo, hi = coords.min(axis=0), coords.max(axis=0)
    pad = 0.06 * float(max(hi - lo)) + 1e-9
    for name, poly in frame.dies.items():
        poly = np.asarray(poly)
        ax.plot(poly[:, 0], poly[:, 1], "-", color=DIE_COLOUR, lw=1.8, gid=f"die:{name}",
                label=f"{name} die", zorder=5)  # fmt: skip
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_aspect("equal")
    ax.set_xlabel(frame.labels[0])
    ax.set_ylabel(frame.labels[1])
    ax.set_title(title)


def die_lines(fig: Figure) -> dict[str, np.ndarray]:
    """The die outlines drawn on a figure's first axes: {name: (k, 2) line data}."""
    return {
        line.get_gid()[4:]: np.asarray(line.get_xydata())
        for line in fig.axes[0].get_lines()
        if (line.get_gid() or "").startswith("die:")
    }


def _figure(nrows: int = 1, ncols: int = 1, *, figsize, **kw):
    """A new Figure on an Agg canvas and its axes (as pyplot.subplots, without pyplot)."""
    fig = Figure(figsize=figsize)
    FigureCanvasAgg(fig)
    return fig, fig.subplots(nrows, ncols, **kw)


def _save(fig: Figure, path: Path) -> Figure:
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    return fig


def stress_strain(curves: dict[str, tuple[np.ndarray, np.ndarray]], path: Path, title: str):
    """curves: label -> (true strain, stress in MPa)."""
    fig, ax = _figure(figsize=(6, 4.2))
    for label, (eps, sig) in curves.items():
        ax.plot(eps, sig, label=label)
    return _finish_curve(
        fig, ax, path, title, "true strain [-]", "true stress [MPa] (compression positive)"
    )


def _finish_curve(fig, ax, path, title, xlabel, ylabel):
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend()
    return _save(fig, path)


def force_stroke(
    stroke_mm, force_n, path: Path, title: str, reference=None, per_die=None, blows=None
):
    """The ram force against the stroke; ``per_die``: {die name: force (N)} of a scene
    with several dies, drawn beside it; ``blows``: the blow of each row (a hammer's
    history column ``blow``), each blow drawn as its own curve from the row before it."""
    fig, ax = _figure(figsize=(6, 4.2))
    if blows is None:
        ax.plot(stroke_mm, force_n, "o-", ms=3, label="jaxform")
    else:
        blows = np.asarray(blows)
        for b in np.unique(blows[blows > 0]):
            rows = np.flatnonzero(blows == b)
            span = np.r_[max(rows[0] - 1, 0), rows]
            ax.plot(np.asarray(stroke_mm)[span], np.asarray(force_n)[span], "o-", ms=3,
                    label=f"blow {int(b)}")  # fmt: skip
    for name, force in (per_die or {}).items():
        ax.plot(stroke_mm, force, "--", lw=1.2, label=f"{name} die")
    if reference is not None:
        ax.plot(reference[0], reference[1], "k--", lw=1, label=reference[2])
    return _finish_curve(fig, ax, path, title, "stroke [mm]", "ram force [N]")


def load_displacement(u_mm, load_n, path: Path, title: str):
    fig, ax = _figure(figsize=(6, 4.2))
    ax.plot(u_mm, load_n, "o-", ms=3, label="jaxform")
    return _finish_curve(fig, ax, path, title, "tip displacement u_y [mm]", "load [N per mm depth]")


def _quads(coords, elements):
    from matplotlib.collections import PolyCollection

    return PolyCollection(coords[elements], closed=True)


@dataclass(frozen=True)
class Marks:
    """Points marked on the deformed-mesh plot (mm): laps (red crosses: the material folded
    onto itself) and pockets (orange circles: air between the material and a die)."""

    laps: tuple = ()
    pockets: tuple = ()


def deformed_mesh(
    coords0,
    coords1,
    elements,
    path: Path,
    title: str,
    axes=("r [mm]", "z [mm]"),
    elements1=None,
    marks=(),
):
    """Deformed mesh (blue) over the initial mesh (grey), as thesis Fig. 6.4; ``elements1``:
    the deformed mesh's elements where it is another mesh (after remeshing); ``marks``: a
    :class:`Marks` (laps and pockets), or (r, z) points of laps; ``axes``: the labels, or a
    :class:`SectionFrame` with the dies at the deformed mesh's instant."""
    marks = marks if isinstance(marks, Marks) else Marks(laps=tuple(marks))
    frame = _frame(axes)
    fig, ax = _figure(figsize=(6, 5))
    for c, e, style in (
        (coords0, elements, dict(edgecolor="0.6", facecolor="none", lw=0.8)),
        (coords1, elements if elements1 is None else elements1,
         dict(edgecolor="tab:blue", facecolor="none", lw=1.0)),
    ):  # fmt: skip
        pc = _quads(c, e)
        pc.set(**style)
        ax.add_collection(pc)
    if len(marks.laps):
        m = np.asarray(marks.laps, dtype=float).reshape(-1, 2)
        ax.plot(m[:, 0], m[:, 1], "x", color="tab:red", ms=9, mew=2, label="lap")
    if len(marks.pockets):
        m = np.asarray(marks.pockets, dtype=float).reshape(-1, 2)
        ax.plot(m[:, 0], m[:, 1], "o", mfc="none", color="tab:orange", ms=10, mew=2,
                label="pocket (underfill)")  # fmt: skip
    _section_axes(ax, frame, np.vstack([coords0, coords1]), title)
    if len(marks.laps) or len(marks.pockets) or frame.dies:
        ax.legend(loc="upper right", fontsize=8)
    return _save(fig, path)


def cell_contours(
    coords, elements, values, path: Path, title: str, label: str, axes=("r [mm]", "z [mm]")
) -> Figure:
    """Cell values (e.g. equivalent plastic strain) on the deformed mesh, as thesis Fig. 6.6.

    A field uniform to round-off (spread <= UNIFORM_RTOL x magnitude) is drawn in one
    colour, its colour bar showing the value itself.

    Arguments:
        coords: (n_nodes, 2) node positions (mm); elements: (n_elements, 4) node ids.
        values: (n_elements,) one value per cell.
        path: the PNG to write; title, label: figure title and colour-bar label.
        axes: the axis labels, or a :class:`SectionFrame` (labels and die outlines).

    Returns:
        the drawn Figure (already saved to ``path``).
    """
    fig, ax = _figure(figsize=(6, 5))
    _cells(fig, ax, coords, elements, values, label)
    _section_axes(ax, _frame(axes), np.asarray(coords), title)
    return _save(fig, path)


def _cells(fig, ax, coords, elements, values, label):
    """The cell field on ``ax`` and its colour bar labelled ``label`` (name [unit])."""
    pc = _quads(coords, elements)
    values = np.asarray(values, dtype=float)
    uniform = _uniform_value(values)
    pc.set_array(values if uniform is None else np.full_like(values, uniform))
    pc.set_cmap("viridis")
    pc.set_edgecolor("k")
    pc.set_linewidth(0.2)
    ax.add_collection(pc)
    if uniform is None:
        fig.colorbar(pc, ax=ax, label=label)
    else:
        half = 0.05 * abs(uniform) or 1.0
        pc.set_clim(uniform - half, uniform + half)
        fig.colorbar(
            pc,
            ax=ax,
            label=f"{label}, uniform",
            ticks=[uniform],
            format=FuncFormatter(lambda x, _: f"{x:.9g}"),
        )
    return pc


def nodal_contours(
    coords, elements, values, path: Path, title: str, label: str, axes=("r [mm]", "z [mm]")
) -> Figure:
    """Filled contours of a nodal field (e.g. the temperature) on the deformed mesh, its
    element edges drawn over them (each quad split into two triangles for the contours).

    Arguments:
        coords: (n_nodes, 2) node positions (mm); elements: (n_elements, 4) node ids.
        values: (n_nodes,) one value per node.
        path: the PNG to write; title, label: figure title and colour-bar label.
        axes: the axis labels, or a :class:`SectionFrame` (labels and die outlines).

    Returns:
        the drawn Figure (already saved to ``path``).
    """
    from matplotlib.tri import Triangulation

    coords, elements = np.asarray(coords), np.asarray(elements)
    values = np.asarray(values, dtype=float)
    tris = np.concatenate([elements[:, [0, 1, 2]], elements[:, [0, 2, 3]]])
    fig, ax = _figure(figsize=(6, 5))
    lo, hi = float(values.min()), float(values.max())
    if hi - lo <= UNIFORM_RTOL * max(abs(hi), 1.0):  # one colour: its value on the bar
        lo, hi = lo - 0.5, hi + 0.5
    cs = ax.tricontourf(Triangulation(coords[:, 0], coords[:, 1], tris), values,
                        levels=np.linspace(lo, hi, 21), cmap="inferno")  # fmt: skip
    pc = _quads(coords, elements)
    pc.set_facecolor("none")
    pc.set_edgecolor("k")
    pc.set_linewidth(0.2)
    ax.add_collection(pc)
    _section_axes(ax, _frame(axes), coords, title)
    fig.colorbar(cs, ax=ax, label=label)
    return _save(fig, path)


def _uniform_value(values: np.ndarray) -> float | None:
    """The field's mean when its spread is round-off (<= UNIFORM_RTOL x its magnitude),
    else None; None too when a value is not finite (drawn as it is)."""
    if values.size == 0 or not np.all(np.isfinite(values)):
        return None
    spread = float(values.max() - values.min())
    if spread > UNIFORM_RTOL * float(np.abs(values).max()):
        return None
    return float(values.mean())


def contact_profiles(profiles: dict, path: Path):
    """profiles: stroke (mm) -> contact_profile dict; pressure and shear of the nodes in
    contact against the arc length along the die they face (``s_mm``, per die: a vertical
    die wall spreads along it where r stands still), or against r for a profile without
    it; slipping nodes filled, sticking nodes open."""
    fig, (ax1, ax2) = _figure(2, 1, figsize=(6.5, 6), sharex=True)
    along = all("s_mm" in p for p in profiles.values())
    for stroke, p in profiles.items():
        on = p["status"] > 0
        dies = np.asarray(p["die"]) if along else np.full(len(on), "")
        colour = None
        for name in dict.fromkeys(dies[on]):  # each die's nodes, in order along it
            sel = on & (dies == name)
            x = np.asarray(p["s_mm"] if along else p["r_mm"])[sel]
            order = np.argsort(x)
            x = x[order]
            label = f"stroke {stroke:.2f} mm" + (f", {name} die" if len(set(dies[on])) > 1 else "")
            (line,) = ax1.plot(x, p["pressure_MPa"][sel][order], "-", color=colour, label=label)
            colour = line.get_color()
            shear = p["shear_MPa"][sel][order]
            slip = p["status"][sel][order] == 2
            ax2.plot(x, shear, "-", color=colour)
            ax2.plot(x[slip], shear[slip], "o", ms=3, color=colour)
            ax2.plot(x[~slip], shear[~slip], "o", ms=4, mfc="none", color=colour)
    ax1.set_ylabel("contact pressure [MPa]")
    ax2.set_ylabel("shear traction [MPa]")
    what = "arc length along the die s [mm]" if along else "r [mm]"
    ax2.set_xlabel(f"{what} (filled: slip, open: stick)")
    ax1.legend(fontsize=8)
    for ax in (ax1, ax2):
        ax.grid(True, alpha=0.3)
    ax1.set_title("contact along the die")
    return _save(fig, path)


def calibration_chart(curves: dict, path: Path):
    """Ring-test calibration chart: curves m -> (height reduction %, inner diameter change %)."""
    fig, ax = _figure(figsize=(6, 4.5))
    for m, (red, did) in curves.items():
        ax.plot(red, did, "-", label=f"m = {m:g}")
    ax.axhline(0.0, color="k", lw=0.6)
    return _finish_curve(
        fig,
        ax,
        path,
        "6:3:2 ring: friction calibration",
        "height reduction [%]",
        "change of inner diameter [%]",
    )


def design_objective(objective, path: Path, title: str, unit: str, simulations=None):
    """Objective against the runs used (``simulations``, each row's count) with the best
    so far, or against optimizer iteration (log scale when it spans decades)."""
    fig, ax = _figure(figsize=(6, 4.2))
    obj = np.asarray(objective, dtype=float)
    x = np.arange(len(obj)) if simulations is None else np.asarray(simulations)
    ax.plot(x, obj, "o-" if simulations is None else "o", ms=3, label="objective")
    if simulations is not None:
        best = np.minimum.accumulate(np.where(np.isfinite(obj), obj, np.inf))
        ax.step(x, best, "k-", where="post", label="best so far")
    fin = obj[np.isfinite(obj)]
    if len(fin) and np.all(fin > 0) and fin.max() > 20 * fin.min():
        ax.set_yscale("log")
    xlabel = "iteration" if simulations is None else "simulations"
    return _finish_curve(fig, ax, path, title, xlabel, f"objective [{unit}]")


def design_comparison(curves: dict, path: Path, title: str, unit: str):
    """Best objective so far against simulations used, one line per optimizer:
    ``curves`` maps a label to (simulations, best objective so far)."""
    fig, ax = _figure(figsize=(6.4, 4.4))
    for label, (sims, best) in curves.items():
        ax.step(np.asarray(sims), np.asarray(best, dtype=float), where="post", label=label)
    vals = np.concatenate([np.asarray(b, dtype=float) for _, b in curves.values()])
    vals = vals[np.isfinite(vals)]
    if len(vals) and np.all(vals > 0) and vals.max() > 20 * vals.min():
        ax.set_yscale("log")
    return _finish_curve(fig, ax, path, title, "simulations", f"best objective [{unit}]")


def die_profiles(rows: list[dict], path: Path):
    """Each designed die's profile at the start (dashed) and at the best design (solid),
    one panel per operation (``rows``: operation, r_mm, z_start_mm, z_designed_mm)."""
    names = list(dict.fromkeys(r["operation"] for r in rows))
    fig, axes = _figure(1, len(names), figsize=(5.2 * len(names), 3.8), squeeze=False)
    for ax, name in zip(axes[0], names):
        own = [r for r in rows if r["operation"] == name]
        r = np.array([row["r_mm"] for row in own])
        ax.plot(r, [row["z_start_mm"] for row in own], "k--", marker=".", label="start")
        ax.plot(r, [row["z_designed_mm"] for row in own], "C3-", marker="o", ms=3,
                label="designed")  # fmt: skip
        ax.set_title(f"{name}: top die")
        ax.set_xlabel("r [mm]")
        ax.set_ylabel("z [mm]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    return _save(fig, path)


def _outline(coords, elements):
    """Boundary edges of a quad mesh (edges used by one element only)."""
    e = np.asarray(elements)
    edges = np.concatenate([e[:, [0, 1]], e[:, [1, 2]], e[:, [2, 3]], e[:, [3, 0]]])
    key = np.sort(edges, axis=1)
    _, inv, count = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return edges[count[inv.ravel()] == 1]


def design_shapes(shapes: dict, path: Path, title: str):
    """shapes: label -> ((n_nodes, 2) positions, (n_el, 4) elements of their mesh);
    outlines drawn over each other."""
    fig, ax = _figure(figsize=(6, 5))
    styles = ["k--", "C0-", "C1-", "C3-", "C2--"]
    for (label, (pos, elements)), style in zip(shapes.items(), styles):
        pos = np.asarray(pos)
        for k, (a, b) in enumerate(_outline(pos, elements)):
            ax.plot(pos[[a, b], 0], pos[[a, b], 1], style, lw=1.2, label=label if k == 0 else None)
    ax.set_aspect("equal")
    ax.set_xlabel("r [mm]")
    ax.set_ylabel("z [mm]")
    ax.set_title(title)
    ax.legend(fontsize=8)
    return _save(fig, path)


def animation(frames, path: Path, title: str, label: str, axes=("r [mm]", "z [mm]"), fps=8):
    """An animation of a run (GIF through matplotlib's Pillow writer): one frame per
    entry of ``frames``, each (time s, stroke mm, node positions (n, 2), elements (m, 4),
    cell values (m,), die outlines {name: (k, 2)}), the field on one colour scale over
    the run, the dies in grey, the axes fixed to the run's extent.  Returns the number
    of frames written."""
    from matplotlib.animation import FuncAnimation, PillowWriter

    frames = list(frames)
    values = np.concatenate([np.asarray(f[4], dtype=float) for f in frames])
    lo, hi = float(values.min()), float(values.max())
    hi = hi if hi > lo else lo + 1.0
    allc = np.vstack([np.asarray(f[2]) for f in frames])
    labels = _frame(axes).labels
    fig, ax = _figure(figsize=(6, 5))

    def draw(k):
        ax.clear()
        t, stroke, pos, elements, vals, dies = frames[k]
        pc = _quads(np.asarray(pos), elements)
        pc.set_array(np.asarray(vals, dtype=float))
        pc.set_cmap("viridis")
        pc.set_clim(lo, hi)
        pc.set_edgecolor("k")
        pc.set_linewidth(0.2)
        ax.add_collection(pc)
        _section_axes(ax, SectionFrame(labels, dies), allc,
                      f"{title}: t = {t:.4g} s, stroke {stroke:.4g} mm")  # fmt: skip
        return (pc,)

    first = draw(0)[0]
    fig.colorbar(first, ax=ax, label=label)
    anim = FuncAnimation(fig, draw, frames=len(frames), blit=False)
    anim.save(str(path), writer=PillowWriter(fps=fps), dpi=80)
    return len(frames)


def flow_lines(coords, elements, polylines, path: Path, title: str, axes=("r [mm]", "z [mm]")):
    """Material lines (``polylines``: a list of (m, 2) arrays, mm) over the deformed section
    (its mesh in light grey): the grain-flow picture; ``axes``: the axis labels, or a
    :class:`SectionFrame` (labels and die outlines)."""
    fig, ax = _figure(figsize=(6, 5))
    pc = _quads(coords, elements)
    pc.set(edgecolor="0.85", facecolor="none", lw=0.5)
    ax.add_collection(pc)
    for p in polylines:
        ax.plot(p[:, 0], p[:, 1], "-", color="tab:blue", lw=1.0)
    _section_axes(ax, _frame(axes), np.asarray(coords), title)
    return _save(fig, path)


def wear_profiles(profiles: dict, path: Path):
    """profiles: die name -> dict(s_mm, wear_mm) (:func:`jaxform.forming_outputs.wear_profiles`):
    the wear depth along each die surface (micrometres against arc length)."""
    fig, ax = _figure(figsize=(6.5, 4))
    for name, p in profiles.items():
        ax.plot(p["s_mm"], 1e3 * np.asarray(p["wear_mm"]), "-", label=f"{name} die")
    ax.set_xlabel("arc length along the die surface from its first station [mm]")
    ax.set_ylabel("wear depth [µm]")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("die wear (Archard)")
    return _save(fig, path)


def process_history(history: dict, names: dict, path: Path, title: str) -> Figure:
    """A multi-stage process over its time: the ram force and, where the history has
    them, the mean, min and max temperature; each operation shaded and named.

    Arguments:
        history: the process history (columns ``time_s``, ``operation``, ``force_N``[,
            ``mean_temperature_K``, ``min_temperature_K``, ``max_temperature_K``]).
        names: {operation index: name}.
        path: the PNG to write; title: the figure's title."""
    t = np.asarray(history["time_s"])
    op = np.asarray(history["operation"])
    heat = "mean_temperature_K" in history
    fig, axes = _figure(2 if heat else 1, 1, figsize=(7, 6 if heat else 3.8), sharex=True)
    axes = np.atleast_1d(axes)
    axes[0].plot(t, history["force_N"], "o-", ms=2.5)
    axes[0].set_ylabel("ram force [N]")
    if heat:
        for k, style in (("mean", "-"), ("min", "--"), ("max", "--")):
            axes[1].plot(t, history[f"{k}_temperature_K"], style, label=k)
        axes[1].set_ylabel("temperature [K]")
        axes[1].legend(fontsize=8)
    for i, index in enumerate(sorted(names)):
        rows = np.flatnonzero(op == index)
        if not len(rows):
            continue
        t0 = t[max(rows[0] - 1, 0)]
        for ax in axes:
            ax.axvspan(t0, t[rows[-1]], color=f"C{i % 10}", alpha=0.12, lw=0)
        axes[0].annotate(names[index], (0.5 * (t0 + t[rows[-1]]), 1.0), xycoords=("data",
                         "axes fraction"), ha="center", va="bottom", fontsize=8)  # fmt: skip
    axes[-1].set_xlabel("process time [s]")
    fig.suptitle(title, fontsize=10)
    return _save(fig, path)
