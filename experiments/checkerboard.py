"""Checkerboard test: equal-order u-p (q1q1) pressure modes against the stabilization factor.

    python experiments/checkerboard.py [--quick] [--meshes 16 32]
                                       [--thetas 0 1e-6 1e-5 1e-4 1e-3 1e-2 0.1 1 10 100]
                                       [--out docs/figures]

Scene: configs/cooks_membrane.toml with q1q1 (nu = 0.4999, F = 1 N, small-strain-like),
``mesh.stabilization`` = theta in tau = theta h^2 / (2 G).  For each theta: the
pressure-oscillation measure (jaxform.postprocess.pressure_oscillation: RMS of the nodal
pressure minus its element-patch average over the RMS pressure; ~1 when a checkerboard
mode dominates) and the tip displacement over the reference (experiments/cooks_membrane.py).
theta = 0 is the unstabilized equal-order element.  theta is a static part of the compiled
program, so each value compiles once per mesh.  --quick: 32 x 32, theta = 0 and 0.1 (the
test suite's compiled programs).

Writes checkerboard.csv and checkerboard.png (oscillation and tip against theta; pressure
fields at theta = 0 and at the seed default 0.1 on the finest mesh).
"""

from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

import numpy as np

import jaxform
from jaxform.config import load_config
from jaxform.postprocess import nodal_fields, pressure_oscillation
from jaxform.scenes import build_scene
from jaxform.simulation import simulate

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "cooks_membrane.toml"
REFERENCE_MM = 0.077587  # linear tip compliance x 1 N (experiments/cooks_membrane.py)
SEED_THETA = 0.1  # the code's default (mesh.stabilization); the seed thesis used 1e-4


def run_theta(n: int, theta: float):
    cfg = load_config(
        CONFIG,
        [
            "mesh.element=q1q1",
            f"mesh.nr={n}",
            f"mesh.nz={n}",
            f"mesh.stabilization={theta!r}",
            "output.fields=false",
            "output.plots=false",
        ],
    )
    t0 = time.perf_counter()
    sc = build_scene(cfg)
    res = simulate(sc)
    x = res.fields["x"][-1]
    return (
        sc,
        x,
        dict(
            oscillation=pressure_oscillation(sc, x),
            tip_uy_mm=float(res.history["tip_uy_mm"][-1]),
            wall_s=time.perf_counter() - t0,
        ),
    )


def plot(rows: dict, fields: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(11, 7.5))
    ax1, ax2 = fig.add_subplot(2, 2, 1), fig.add_subplot(2, 2, 2)
    th = np.asarray(rows["theta"], dtype=float)
    positive = th[th > 0]
    zero_at = positive.min() / 10.0 if positive.size else 1e-7  # theta = 0 drawn here
    for n in sorted(set(rows["elements_per_side"])):
        sel = np.asarray(rows["elements_per_side"]) == n
        x = np.where(th[sel] > 0, th[sel], zero_at)
        order = np.argsort(x)
        ax1.loglog(x[order], np.asarray(rows["oscillation"])[sel][order], "o-", label=f"{n} x {n}")
        ax2.semilogx(
            x[order],
            np.asarray(rows["tip_uy_mm"])[sel][order] / REFERENCE_MM,
            "o-",
            label=f"{n} x {n}",
        )
    for ax in (ax1, ax2):
        ax.axvline(SEED_THETA, color="tab:red", lw=1, ls=":", label="default 0.1")
        ax.axvline(1e-4, color="0.5", lw=1, ls=":", label="thesis 1e-4")
        ax.axvline(zero_at, color="k", lw=0.5)
        ax.set_xlabel("stabilization theta (leftmost point: theta = 0)")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    ax1.set_ylabel("pressure oscillation (RMS(p - patch avg) / RMS(p))")
    ax2.axhspan(0.98, 1.02, color="0.85", zorder=0)
    ax2.set_ylabel("tip displacement / reference")
    for k, (theta, (coords, elements, p)) in enumerate(fields.items()):
        ax = fig.add_subplot(2, 2, 3 + k)
        tri = np.vstack([elements[:, [0, 1, 2]], elements[:, [0, 2, 3]]])
        lim = np.percentile(np.abs(p), 99)
        pc = ax.tripcolor(
            coords[:, 0],
            coords[:, 1],
            tri,
            p,
            shading="gouraud",
            cmap="coolwarm",
            vmin=-lim,
            vmax=lim,
        )
        ax.set_xlim(coords[:, 0].min(), coords[:, 0].max())
        ax.set_ylim(coords[:, 1].min(), coords[:, 1].max())
        ax.set_aspect("equal")
        ax.set_title(f"nodal pressure, theta = {theta:g}")
        fig.colorbar(pc, ax=ax, label="pressure [MPa]")
    fig.suptitle("q1q1 on Cook's membrane (nu = 0.4999): checkerboard against stabilization")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="32 x 32, theta = 0 and 0.1 (CI)")
    ap.add_argument("--meshes", type=int, nargs="+", default=[16, 32])
    ap.add_argument(
        "--thetas",
        type=float,
        nargs="+",
        default=[0.0, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 0.1, 1.0, 10.0, 100.0],
    )
    ap.add_argument("--out", default="docs/figures")
    args = ap.parse_args(argv)
    jaxform.enable_x64()
    meshes = [32] if args.quick else sorted(args.meshes)
    thetas = [0.0, SEED_THETA] if args.quick else args.thetas
    if any(t < 0 for t in thetas):
        raise SystemExit(f"--thetas {thetas}: every value must be >= 0")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = {k: [] for k in ("elements_per_side", "theta", "oscillation", "tip_uy_mm", "wall_s")}
    fields = {}
    for n in meshes:
        for theta in thetas:
            sc, x, r = run_theta(n, theta)
            for k, v in (
                ("elements_per_side", n),
                ("theta", theta),
                ("oscillation", r["oscillation"]),
                ("tip_uy_mm", r["tip_uy_mm"]),
                ("wall_s", r["wall_s"]),
            ):
                rows[k].append(v)
            print(
                f"{n:3d}x{n:<3d} theta = {theta:8.1e}: oscillation {r['oscillation']:.4f}, "
                f"tip {r['tip_uy_mm'] / REFERENCE_MM:.4f} of the reference "
                f"({r['wall_s']:.1f} s)",
                flush=True,
            )
            if n == meshes[-1] and theta in (0.0, SEED_THETA):
                u, p, _ = nodal_fields(sc, x)
                fields[theta] = (np.asarray(sc.mesh.coords) + u, np.asarray(sc.mesh.elements), p)
    with open(out / "checkerboard.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(list(rows))
        for values in zip(*rows.values()):
            w.writerow([f"{v:.10g}" if isinstance(v, float) else v for v in values])
    plot(rows, fields, out / "checkerboard.png")
    print(f"wrote {out / 'checkerboard.csv'} and {out / 'checkerboard.png'}")
    return rows


if __name__ == "__main__":
    main()
