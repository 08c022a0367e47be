"""Prandtl's flat punch: pressure against punch travel for q4, q1p0 and q1q1, and the limit
pressure against the slip-line value (2 + pi) k.

    python experiments/prandtl_punch.py [--quick] [--per-a 4.5 8.5 16.5 32.5]
                                        [--elements q4 q1p0 q1q1] [--out docs/figures]

Scene: configs/prandtl_punch.toml (rigid frictionless punch of half-width a = 1.0625 mm on
a 12 x 12 mm plane-strain block of the nearly rigid J2 solid j2_rigid_plastic_100MPa,
k = sigma_y / sqrt(3)).  A refinement is the number m of equal elements across the punch
half-width in the fine zone under the punch (h = a / m); m is a half-integer so that the
punch corner lies in the middle of an element.  The fine zone stays ~3 mm x 2 mm.

Limit pressure: force_N / a at the end of the run (travel 0.0018 mm ~ 0.0017 a); q1p0 and
q1q1 reach a plateau at ~0.001 a (later rise < 0.05 % per step, the change of geometry);
q4 locks and keeps rising.  --quick: m = 4.5 for q4 and 8.5 for q1p0 and q1q1 (the test
suite's compiled programs).

Writes prandtl_punch.csv (element, m, travel, pressure ratio per step) and
prandtl_punch.png (pressure / (2 + pi) k against travel / a; limit ratio against m).
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

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "prandtl_punch.toml"
ELEMENTS = ("q4", "q1p0", "q1q1")
QUICK = {"q4": 4.5, "q1p0": 8.5, "q1q1": 8.5}


def punch_overrides(
    per_a: float, a_mm: float, fine_width_mm: float = 3.0, fine_depth_mm: float = 2.0
) -> list[str]:
    """Config overrides for m = per_a equal elements across the punch half-width a."""
    if abs(per_a - math.floor(per_a) - 0.5) > 1e-9:
        raise SystemExit(f"--per-a {per_a}: must be a half-integer (punch corner mid-element)")
    h = a_mm / per_a
    nr, nz = round(fine_width_mm / h), round(fine_depth_mm / h)
    return [
        f"mesh.nr={nr}",
        f"mesh.nz={nz}",
        f"block.fine_width_mm={nr * h!r}",
        f"block.fine_depth_mm={nz * h!r}",
    ]


def limit_run(element: str, per_a: float) -> dict:
    """Pressure ratio p / ((2 + pi) k) against travel / a for one element and refinement."""
    base = load_config(CONFIG)
    a_mm = base["die"]["profile_mm"][1][0]
    cfg = load_config(
        CONFIG,
        [f"mesh.element={element}", "output.fields=false", "output.plots=false"]
        + punch_overrides(per_a, a_mm),
    )
    sc = build_scene(cfg)
    k = float(sc.inputs.params.sigma_y0_MPa) / math.sqrt(3.0)
    t0 = time.perf_counter()
    res = simulate(sc)
    h = res.history
    return dict(
        travel_over_a=h["stroke_mm"] / a_mm,
        ratio=h["force_N"] / a_mm / ((2.0 + math.pi) * k),
        newton_iterations=int(h["newton_iterations"].sum()),
        cutbacks=int(h["cutbacks"].sum()),
        n_elements=sc.mesh.n_elements,
        wall_s=time.perf_counter() - t0,
    )


def plot(curves: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.3))
    colors = {"q4": "tab:red", "q1p0": "tab:blue", "q1q1": "tab:green"}
    styles = ["-", "--", "-.", ":"]
    per_as = sorted({m for _, m in curves})
    for (el, m), c in sorted(curves.items()):
        ax1.plot(
            c["travel_over_a"],
            c["ratio"],
            styles[per_as.index(m) % 4],
            color=colors[el],
            label=f"{el}, a/h = {m:g}",
        )
    for el in ELEMENTS:
        sel = sorted((m, c["ratio"][-1]) for (e, m), c in curves.items() if e == el)
        if sel:
            m, r = np.array(sel).T
            ax2.semilogx(m, r, "o-", base=2, color=colors[el], label=el)
    for ax in (ax1, ax2):
        ax.axhline(1.0, color="k", lw=1, ls="--", label="(2 + pi) k")
        ax.axhspan(0.98, 1.02, color="0.85", zorder=0)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    ax1.set_xlabel("punch travel / a")
    ax1.set_ylabel("mean punch pressure / (2 + pi) k")
    ax2.set_xlabel("elements across the punch half-width a / h")
    ax2.set_ylabel("limit pressure / (2 + pi) k")
    ax1.set_title("pressure against travel")
    ax2.set_title("limit pressure against mesh")
    fig.suptitle("Prandtl's flat punch (plane strain, frictionless, J2)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one mesh per element (CI)")
    ap.add_argument("--per-a", type=float, nargs="+", default=[4.5, 8.5, 16.5, 32.5])
    ap.add_argument("--elements", nargs="+", default=list(ELEMENTS), choices=ELEMENTS)
    ap.add_argument("--out", default="docs/figures")
    args = ap.parse_args(argv)
    jaxform.enable_x64()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    runs = (
        [(el, QUICK[el]) for el in args.elements]
        if args.quick
        else [(el, m) for el in args.elements for m in sorted(args.per_a)]
    )
    curves = {}
    for el, m in runs:
        c = limit_run(el, m)
        curves[(el, m)] = c
        print(
            f"{el:5s} a/h = {m:5g} ({c['n_elements']} elements): limit pressure "
            f"{c['ratio'][-1]:.4f} (2 + pi) k, {c['newton_iterations']} Newton its, "
            f"{c['cutbacks']} cutbacks, {c['wall_s']:.1f} s",
            flush=True,
        )
    with open(out / "prandtl_punch.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["element", "per_a", "travel_over_a", "pressure_over_2_plus_pi_k"])
        for (el, m), c in curves.items():
            for t, r in zip(c["travel_over_a"], c["ratio"]):
                w.writerow([el, f"{m:g}", f"{t:.10g}", f"{r:.10g}"])
    plot(curves, out / "prandtl_punch.png")
    print(f"wrote {out / 'prandtl_punch.csv'} and {out / 'prandtl_punch.png'}")
    return curves


if __name__ == "__main__":
    main()
