"""A hammer forging of the seed billet: blows, force-stroke per blow, a section with dies.

    python experiments/hammer_forging.py [--mesh 6 6] [--energy-j 0.25] [--blows 4]
                                         [--steps 6] [--out docs/figures]

The seed billet (Al 1100-O at 673 K, 5 x 7.5 mm, half height) with Coulomb friction 0.3
(configs/upsetting_friction.toml)
under a hammer: blows of ``--energy-j`` J at efficiency 0.8 and impact speed 500 mm/s.
Writes hammer_blows.csv (per blow: its work on the part from the force-stroke history
by the trapezoid rule, efficiency x energy, the height after it, its duration),
hammer_force_stroke.png (force against stroke, one curve per blow) and
hammer_section.png (equivalent plastic strain after the last blow, the dies where they
stand).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import jaxform
from jaxform import plot
from jaxform.config import load_config
from jaxform.io import write_csv
from jaxform.postprocess import die_outlines, positions
from jaxform.scenes import build_scene
from jaxform.simulation import simulate


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--mesh", type=int, nargs=2, default=[6, 6])
    ap.add_argument("--energy-j", type=float, default=0.25)
    ap.add_argument("--blows", type=int, default=4)
    ap.add_argument("--steps", type=int, default=6)
    ap.add_argument("--out", default="docs/figures")
    args = ap.parse_args()
    jaxform.enable_x64()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    eff = 0.8
    cfg = load_config(
        "configs/upsetting_friction.toml",
        [
            f"mesh.nr={args.mesh[0]}",
            f"mesh.nz={args.mesh[1]}",
            "press.model=hammer",
            f"press.energy_J={args.energy_j}",
            f"press.efficiency={eff}",
            "press.impact_speed_mm_s=500",
            f"press.blows={args.blows}",
            f"press.steps_per_blow={args.steps}",
        ],
    )
    start = time.perf_counter()
    scene = build_scene(cfg)
    res = simulate(scene)
    wall = time.perf_counter() - start
    h = res.history
    height0 = scene.workpiece.reference_height_mm
    rows = {"blow": [], "work_Nmm": [], "target_Nmm": [], "height_mm": [], "duration_s": []}
    for b in range(1, args.blows + 1):
        sel = np.flatnonzero(h["blow"] == b)
        span = np.r_[sel[0] - 1, sel]
        rows["blow"].append(b)
        rows["work_Nmm"].append(float(np.trapezoid(h["force_N"][span], h["stroke_mm"][span])))
        rows["target_Nmm"].append(eff * args.energy_j * 1000.0)
        rows["height_mm"].append(height0 - float(h["stroke_mm"][sel[-1]]))
        rows["duration_s"].append(float(h["time_s"][sel[-1]] - h["time_s"][span[0]]))
    write_csv(out / "hammer_blows.csv", rows)
    title = (
        f"hammer on the seed billet: {args.blows} blows of {args.energy_j:g} J (efficiency {eff:g})"
    )
    plot.force_stroke(h["stroke_mm"], h["force_N"], out / "hammer_force_stroke.png", title,
                      blows=h["blow"])  # fmt: skip
    t = float(h["time_s"][-1])
    final = positions(scene, res.fields["x"][-1])
    plot.cell_contours(
        final,
        np.asarray(scene.mesh.elements),
        res.fields["eqps"][-1].mean(axis=1),
        out / "hammer_section.png",
        f"after blow {args.blows}: height {rows['height_mm'][-1]:.3f} mm",
        "equivalent plastic strain [-]",
        plot.SectionFrame(("r [mm]", "z [mm]"), die_outlines(res.scene, t)),
    )
    for k in range(args.blows):
        print(
            f"blow {rows['blow'][k]}: work {rows['work_Nmm'][k]:.6f} N mm "
            f"(target {rows['target_Nmm'][k]:.6f}), height {rows['height_mm'][k]:.4f} mm, "
            f"{rows['duration_s'][k] * 1e3:.3f} ms"
        )
    print(f"{len(h['time_s']) - 1} steps, {wall:.1f} s wall")


if __name__ == "__main__":
    main()
