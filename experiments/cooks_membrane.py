"""Cook's membrane at nu = 0.4999: tip deflection against mesh size for q4, q1p0, q1q1.

    python experiments/cooks_membrane.py [--quick] [--meshes 2 4 8 16 32 64 128]
                                         [--elements q4 q1p0 q1q1] [--out docs/figures]

configs/cooks_membrane.toml (E = 250 MPa, nu = 0.4999, plane strain, left edge clamped,
uniform shear on the right edge) under two loads, both dead loads:

* small-strain-like: F = 1 N per mm of depth in one step; rotations stay ~1e-3, so
  tip_uy_mm / F is the linear-elastic compliance to ~1e-3;
* finite strain: F = 100 N per mm of depth in 10 steps (hypoelastic material; the tip moves
  ~6.7 mm, rotations ~0.2).

Both loads share one compiled program per (element, mesh).  The reference of each load is
this script's own Richardson extrapolation of the q1p0 and q1q1 tips on the three finest
meshes (observed order from the three; printed, and written to the CSV with mesh = 0); the
README quotes the values of a full run (meshes up to 128 x 128), which tests/test_verification.py
uses as constants.  --quick: one mesh (32 x 32), the three elements, both loads (the test
suite's compiled programs), reference lines from those constants.

Writes cooks_membrane.csv (element, elements per side, load, tip displacement, Newton
iterations, wall time) and cooks_membrane.png (tip displacement / reference against mesh).
"""

from __future__ import annotations

import argparse
import csv
import math
import time
from pathlib import Path

import numpy as np

import jaxform
from jaxform.config import load_config
from jaxform.scenes import build_scene
from jaxform.simulation import simulate

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "cooks_membrane.toml"
# (load N per mm of depth, time step s): one step for the small load, ten for the large one
LOADS = {"small strain (F = 1 N)": (1.0, 1.0), "finite strain (F = 100 N)": (100.0, 0.1)}
# Richardson extrapolations of q1p0/q1q1 at 32/64/128 (full run of this script, README)
REFERENCE_MM = {1.0: 0.077587, 100.0: 6.7188}
ELEMENTS = ("q4", "q1p0", "q1q1")


def tip_deflection(element: str, n: int, force_n: float, dt_s: float) -> dict:
    """One run: tip u_y (mm) at the full load, Newton iterations, wall time."""
    cfg = load_config(
        CONFIG,
        [
            f"mesh.element={element}",
            f"mesh.nr={n}",
            f"mesh.nz={n}",
            f"load.force_y_N={force_n}",
            f"time.dt_s={dt_s}",
            "output.fields=false",
            "output.plots=false",
        ],
    )
    t0 = time.perf_counter()
    res = simulate(build_scene(cfg))
    return dict(
        tip_uy_mm=float(res.history["tip_uy_mm"][-1]),
        newton_iterations=int(res.history["newton_iterations"].sum()),
        wall_s=time.perf_counter() - t0,
    )


def richardson(meshes, values) -> tuple[float, float]:
    """Extrapolated value and observed order from the last three of successive doublings."""
    (n1, n2, n3), (u1, u2, u3) = meshes[-3:], values[-3:]
    if not (n2 == 2 * n1 and n3 == 2 * n2):
        raise ValueError("Richardson extrapolation needs three successive mesh doublings")
    p = math.log(abs((u2 - u1) / (u3 - u2))) / math.log(2.0)
    return u3 + (u3 - u2) / (2.0**p - 1.0), p


def write_table(path: Path, rows: dict) -> None:
    """CSV with a header line; text and numbers as they are."""
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(list(rows))
        for values in zip(*rows.values()):
            w.writerow([f"{v:.10g}" if isinstance(v, float) else v for v in values])


def plot(rows: dict, references: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2), sharey=True)
    for ax, (label, (force, _)) in zip(axes, LOADS.items()):
        ref = references[force]
        for el in ELEMENTS:
            sel = [
                (n, u)
                for e, n, f, u in zip(
                    rows["element"], rows["elements_per_side"], rows["load_N"], rows["tip_uy_mm"]
                )
                if e == el and f == force and n > 0
            ]
            if sel:
                n, u = np.array(sel).T
                ax.semilogx(n, u / ref, "o-", base=2, label=el)
        ax.axhline(1.0, color="k", ls="--", lw=1, label=f"reference {ref:.5g} mm")
        ax.axhspan(0.98, 1.02, color="0.85", zorder=0, label="+-2 %")
        ax.set_xlabel("elements per side")
        ax.set_title(label)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    axes[0].set_ylabel("tip displacement u_y / reference")
    fig.suptitle("Cook's membrane, plane strain, nu = 0.4999")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one mesh (32 x 32): CI smoke run")
    ap.add_argument("--meshes", type=int, nargs="+", default=[2, 4, 8, 16, 32, 64, 128])
    ap.add_argument("--elements", nargs="+", default=list(ELEMENTS), choices=ELEMENTS)
    ap.add_argument("--out", default="docs/figures")
    args = ap.parse_args(argv)
    jaxform.enable_x64()
    meshes = [32] if args.quick else sorted(args.meshes)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = {
        k: []
        for k in (
            "element",
            "elements_per_side",
            "load_N",
            "tip_uy_mm",
            "newton_iterations",
            "wall_s",
        )
    }
    tips: dict = {}
    for el in args.elements:
        for n in meshes:
            for force, dt in LOADS.values():
                r = tip_deflection(el, n, force, dt)
                tips[(el, n, force)] = r["tip_uy_mm"]
                for k, v in (
                    ("element", el),
                    ("elements_per_side", n),
                    ("load_N", force),
                    ("tip_uy_mm", r["tip_uy_mm"]),
                    ("newton_iterations", r["newton_iterations"]),
                    ("wall_s", r["wall_s"]),
                ):
                    rows[k].append(v)
                print(
                    f"{el:5s} {n:4d}x{n:<4d} F = {force:5g} N: tip u_y = {r['tip_uy_mm']:.6g} mm "
                    f"({r['tip_uy_mm'] / REFERENCE_MM[force]:.4f} of the reference), "
                    f"{r['newton_iterations']} Newton its, {r['wall_s']:.1f} s",
                    flush=True,
                )
    references = dict(REFERENCE_MM)
    if len(meshes) >= 3 and meshes[-1] >= 64:
        for force in (f for f, _ in LOADS.values()):
            ext = []
            for el in ("q1p0", "q1q1"):
                if el in args.elements:
                    u, p = richardson(meshes, [tips[(el, n, force)] for n in meshes])
                    ext.append(u)
                    print(f"Richardson ({el}, F = {force:g} N): {u:.6g} mm, observed order {p:.2f}")
                    for k, v in (
                        ("element", f"{el}_richardson"),
                        ("elements_per_side", 0),
                        ("load_N", force),
                        ("tip_uy_mm", u),
                        ("newton_iterations", 0),
                        ("wall_s", 0.0),
                    ):
                        rows[k].append(v)
            if ext:
                references[force] = float(np.mean(ext))
    write_table(out / "cooks_membrane.csv", rows)
    plot(rows, references, out / "cooks_membrane.png")
    print(f"wrote {out / 'cooks_membrane.csv'} and {out / 'cooks_membrane.png'}")
    return {"rows": rows, "references": references}


if __name__ == "__main__":
    main()
