"""PNG figures (matplotlib, Agg backend: no display needed)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def stress_strain(curves: dict[str, tuple[np.ndarray, np.ndarray]], path: Path, title: str):
    """curves: label -> (true strain, stress in MPa)."""
    fig, ax = plt.subplots(figsize=(6, 4.2))
    for label, (eps, sig) in curves.items():
        ax.plot(eps, sig, label=label)
    _finish_curve(fig, ax, path, title, "true strain [-]",
                  "true stress [MPa] (compression positive)")


def _finish_curve(fig, ax, path, title, xlabel, ylabel):
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def force_stroke(stroke_mm, force_n, path: Path, title: str, reference=None):
    fig, ax = plt.subplots(figsize=(6, 4.2))
    ax.plot(stroke_mm, force_n, "o-", ms=3, label="jaxform")
    if reference is not None:
        ax.plot(reference[0], reference[1], "k--", lw=1, label=reference[2])
    _finish_curve(fig, ax, path, title, "stroke [mm]", "ram force [N]")


def load_displacement(u_mm, load_n, path: Path, title: str):
    fig, ax = plt.subplots(figsize=(6, 4.2))
    ax.plot(u_mm, load_n, "o-", ms=3, label="jaxform")
    _finish_curve(fig, ax, path, title, "tip displacement u_y [mm]", "load [N per mm depth]")


def _quads(coords, elements):
    from matplotlib.collections import PolyCollection

    return PolyCollection(coords[elements], closed=True)


def deformed_mesh(coords0, coords1, elements, path: Path, title: str,
                  axes=("r [mm]", "z [mm]")):
    """Deformed mesh (blue) over the initial mesh (grey), as thesis Fig. 6.4."""
    fig, ax = plt.subplots(figsize=(6, 5))
    for c, style in ((coords0, dict(edgecolor="0.6", facecolor="none", lw=0.8)),
                     (coords1, dict(edgecolor="tab:blue", facecolor="none", lw=1.0))):
        pc = _quads(c, elements)
        pc.set(**style)
        ax.add_collection(pc)
    allc = np.vstack([coords0, coords1])
    ax.set_xlim(allc[:, 0].min() - 0.1, allc[:, 0].max() * 1.05 + 0.1)
    ax.set_ylim(allc[:, 1].min() - 0.1, allc[:, 1].max() * 1.05 + 0.1)
    ax.set_aspect("equal")
    ax.set_xlabel(axes[0])
    ax.set_ylabel(axes[1])
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def cell_contours(coords, elements, values, path: Path, title: str, label: str,
                  axes=("r [mm]", "z [mm]")):
    """Cell values (e.g. equivalent plastic strain) on the deformed mesh, as thesis Fig. 6.6."""
    fig, ax = plt.subplots(figsize=(6, 5))
    pc = _quads(coords, elements)
    pc.set_array(np.asarray(values))
    pc.set_cmap("viridis")
    pc.set_edgecolor("k")
    pc.set_linewidth(0.2)
    ax.add_collection(pc)
    ax.set_xlim(coords[:, 0].min(), coords[:, 0].max() * 1.02)
    ax.set_ylim(coords[:, 1].min(), coords[:, 1].max() * 1.02)
    ax.set_aspect("equal")
    ax.set_xlabel(axes[0])
    ax.set_ylabel(axes[1])
    ax.set_title(title)
    fig.colorbar(pc, ax=ax, label=label)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def contact_profiles(profiles: dict, path: Path):
    """profiles: stroke (mm) -> contact_profile dict; pressure and shear vs radius of the
    nodes in contact, slipping nodes filled, sticking nodes open."""
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(6.5, 6), sharex=True)
    for stroke, p in profiles.items():
        on = p["status"] > 0
        order = np.argsort(p["r_mm"][on])
        r = p["r_mm"][on][order]
        line, = ax1.plot(r, p["pressure_MPa"][on][order], "-", label=f"stroke {stroke:.2f} mm")
        ax2.plot(r, p["shear_MPa"][on][order], "-", color=line.get_color())
        slip = p["status"][on][order] == 2
        ax2.plot(r[slip], p["shear_MPa"][on][order][slip], "o", ms=3, color=line.get_color())
        ax2.plot(r[~slip], p["shear_MPa"][on][order][~slip], "o", ms=4, mfc="none",
                 color=line.get_color())
    ax1.set_ylabel("contact pressure [MPa]")
    ax2.set_ylabel("shear traction [MPa]")
    ax2.set_xlabel("r [mm] (filled: slip, open: stick)")
    ax1.legend(fontsize=8)
    for ax in (ax1, ax2):
        ax.grid(True, alpha=0.3)
    ax1.set_title("contact along the die")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def calibration_chart(curves: dict, path: Path):
    """Ring-test calibration chart: curves m -> (height reduction %, inner diameter change %)."""
    fig, ax = plt.subplots(figsize=(6, 4.5))
    for m, (red, did) in curves.items():
        ax.plot(red, did, "-", label=f"m = {m:g}")
    ax.axhline(0.0, color="k", lw=0.6)
    _finish_curve(fig, ax, path, "6:3:2 ring: friction calibration", "height reduction [%]",
                  "change of inner diameter [%]")


def design_objective(objective, path: Path, title: str, unit: str):
    """Objective against optimizer iteration (log scale when it spans decades)."""
    fig, ax = plt.subplots(figsize=(6, 4.2))
    obj = np.asarray(objective)
    ax.plot(np.arange(len(obj)), obj, "o-", label="objective")
    if np.all(obj > 0) and obj.max() > 20 * obj.min():
        ax.set_yscale("log")
    _finish_curve(fig, ax, path, title, "iteration", f"objective [{unit}]")


def _outline(coords, elements):
    """Boundary edges of a quad mesh (edges used by one element only)."""
    e = np.asarray(elements)
    edges = np.concatenate([e[:, [0, 1]], e[:, [1, 2]], e[:, [2, 3]], e[:, [3, 0]]])
    key = np.sort(edges, axis=1)
    _, inv, count = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return edges[count[inv.ravel()] == 1]


def design_shapes(shapes: dict, elements, path: Path, title: str):
    """shapes: label -> (n_nodes, 2) positions; outlines drawn over each other."""
    fig, ax = plt.subplots(figsize=(6, 5))
    styles = ["k--", "C0-", "C1-", "C3-", "C2--"]
    for (label, pos), style in zip(shapes.items(), styles):
        pos = np.asarray(pos)
        for k, (a, b) in enumerate(_outline(pos, elements)):
            ax.plot(pos[[a, b], 0], pos[[a, b], 1], style, lw=1.2,
                    label=label if k == 0 else None)
    ax.set_aspect("equal")
    ax.set_xlabel("r [mm]")
    ax.set_ylabel("z [mm]")
    ax.set_title(title)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
