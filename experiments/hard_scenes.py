"""Hard scenes at their own time step: outcome, reduction reached, steps, cutbacks, Newton
iterations per step, the largest node-to-node oscillation of the shear traction along the
die and wall time, as a markdown table and a CSV.

    python experiments/hard_scenes.py [--only NAME ...] [--out docs/figures/hard_scenes.csv]

The scenes are the large-deformation runs that stopped after cutbacks at the configured
``time.dt_s`` before steps adapted (ring with high shear friction on a fine mesh,
upsetting with friction to 80 %, sticking friction, the closed die on 20 x 20), plus the
shipped scenes with a die.  Each runs in this process, one after another (wall time
includes compilation).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import jaxform

SCENES = {
    "ring m=0.5 24x12": (
        "configs/ring_compression.toml",
        ["friction.m=0.5", "mesh.nr=24", "mesh.nz=12"],
    ),
    "ring m=0.5 24x12 q1p0": (
        "configs/ring_compression.toml",
        ["friction.m=0.5", "mesh.nr=24", "mesh.nz=12", "mesh.element=q1p0"],
    ),
    "ring m=1.0 24x12": (
        "configs/ring_compression.toml",
        ["friction.m=1.0", "mesh.nr=24", "mesh.nz=12"],
    ),
    "friction 80% 10x10": ("configs/upsetting_friction.toml", ["die.reduction=0.8"]),
    "friction 80% 20x20": (
        "configs/upsetting_friction.toml",
        ["die.reduction=0.8", "mesh.nr=20", "mesh.nz=20"],
    ),
    "sticking 80% 10x10": (
        "configs/upsetting_friction.toml",
        ["die.reduction=0.8", "friction.model=sticking"],
    ),
    "closed die 20x20": ("configs/closed_die.toml", ["mesh.nr=20", "mesh.nz=20"]),
    "friction q1p0 dt 20 s": (
        "configs/upsetting_friction.toml",
        ["mesh.element=q1p0", "time.dt_s=20"],
    ),
    "seed": ("configs/upsetting_seed.toml", []),
    "friction": ("configs/upsetting_friction.toml", []),
    "ring": ("configs/ring_compression.toml", []),
    "closed die": ("configs/closed_die.toml", []),
}
QUIET = ["output.plots=false", "output.fields=false"]


def shear_zigzag(res) -> float:
    """The largest node-to-node oscillation of the shear traction along the die (MPa) over
    the run's rows (jaxform.postprocess.zigzag)."""
    from jaxform.postprocess import contact_profile, zigzag

    f = res.fields
    return max(
        zigzag(contact_profile(res.scene, f["x"][k], f["slip_mm"][k], f["contact_status"][k]))
        for k in range(len(f["x"]))
    )


def run_one(config: str, overrides: list[str]) -> dict:
    from jaxform.simulation import SimulationError

    cfg = jaxform.load_config(config, overrides + QUIET)
    t0 = time.perf_counter()
    failure = ""
    try:
        res = jaxform.run(cfg)
    except SimulationError as err:
        res, failure = err.result, str(err)
    wall = time.perf_counter() - t0
    h = res.history
    height = res.scene.workpiece.reference_height_mm
    steps = len(h["time_s"]) - 1
    return dict(
        outcome="failed" if failure else "completed",
        reduction_pct=100.0 * h["stroke_mm"][-1] / height,
        target_pct=100.0 * cfg["die"]["reduction"],
        steps=steps,
        cutbacks=int(h["cutbacks"].sum()),
        newton_per_step=float(h["newton_iterations"][1:].sum() / max(steps, 1)),
        min_dt_s=float(h["dt_s"][1:].min()) if steps else float("nan"),
        zigzag_MPa=shear_zigzag(res),
        wall_s=wall,
        failure=failure,
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="*", default=None, help="scene names to run")
    ap.add_argument("--out", default="docs/figures/hard_scenes.csv")
    args = ap.parse_args()
    jaxform.enable_x64()
    jaxform.enable_compilation_cache()
    names = args.only or list(SCENES)
    rows = []
    print(
        "| scene | outcome | reduction % (target) | steps | cutbacks | Newton/step | "
        "smallest dt (s) | shear zigzag (MPa) | wall (s) |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for name in names:
        config, over = SCENES[name]
        r = run_one(config, over)
        rows.append((name, r))
        print(
            f"| {name} | {r['outcome']} | {r['reduction_pct']:.2f} ({r['target_pct']:.1f}) | "
            f"{r['steps']} | {r['cutbacks']} | {r['newton_per_step']:.2f} | "
            f"{r['min_dt_s']:.3g} | {r['zigzag_MPa']:.2f} | {r['wall_s']:.1f} |",
            flush=True,
        )
        if r["failure"]:
            print(f"  ({r['failure']})", flush=True)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    keys = [
        "outcome",
        "reduction_pct",
        "target_pct",
        "steps",
        "cutbacks",
        "newton_per_step",
        "min_dt_s",
        "zigzag_MPa",
        "wall_s",
    ]
    with open(out, "w") as fh:
        fh.write("scene," + ",".join(keys) + "\n")
        for name, r in rows:
            fh.write(
                name
                + ","
                + ",".join(str(r[k]) if isinstance(r[k], str) else f"{r[k]:.6g}" for k in keys)
                + "\n"
            )
    print(f"wrote {out}")


if __name__ == "__main__":
    np.set_printoptions(precision=4)
    main()
