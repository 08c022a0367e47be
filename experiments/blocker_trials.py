"""Hand trials of a process's blocker: other die shapes for one forming operation, each run
whole at the given billet volumes, side by side with the configured die.

A forging engineer checks a blocker idea by running it: this writes one process config per
shape (the operation's top-die profile replaced; the shape is given where the die stands
at the operation's end, and the die starts as high at the axis as the configured one, so
its travel is whatever that takes) and runs each at each billet scale with
``experiments/billet_volume_sweep.py``'s runner (``jaxform run`` in its own process).
``--raise-mm`` lifts a later operation's die at its start (its stroke grows alike and its
end stays), so that a blocked part taller than the configured one still starts clear of it.

    python experiments/blocker_trials.py CONFIG --shape NAME='r,z;r,z;...' [--shape ...]
        [--operation blocker] [--raise finisher=0.5] [--scales 0.945] [--jobs 2]
        [--set section.key=value ...] [--out out/blocker_trials]

writes ``trials.csv`` (one row per shape and scale: the last forming operation's die fill
and flash, each blow's peak force, laps, pockets; a run that stops: its one line), each
config and run in ``<shape>/``, and ``profiles.png`` (each shape at its end over the
last forming operation's die at its end).
"""

from __future__ import annotations

import argparse
import csv
import tomllib
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import tomli_w
from billet_volume_sweep import COLUMNS, run_scale


def parse_shape(text: str) -> tuple[str, np.ndarray]:
    """'NAME=r,z;r,z;...' -> (name, (n, 2) points in mm)."""
    name, _, pts = text.partition("=")
    try:
        xy = np.array([[float(v) for v in p.split(",")] for p in pts.split(";")])
    except ValueError:
        xy = np.zeros((0, 0))
    bad = xy.ndim != 2 or xy.shape[1] != 2 or len(xy) < 2
    if not name or bad or np.any(np.diff(xy[:, 0]) < 0):
        raise SystemExit(
            f"--shape {text!r}: NAME='r,z;r,z;...' with at least 2 points, r non-decreasing (mm)"
        )
    return name, xy


def operations(doc: dict) -> dict[str, dict]:
    return {op.get("name", op["kind"]): op for op in doc["process"]["operation"]}


def with_shape(doc: dict, operation: str, end: np.ndarray, raises: dict[str, float]) -> dict:
    """A copy of the process document with ``operation``'s top die at ``end`` (its end
    position), starting as high at the axis as the configured die, and each die in
    ``raises`` lifted at its start by that many mm (its travel or final gap kept)."""
    new = tomllib.loads(tomli_w.dumps(doc))
    ops = operations(new)
    op = ops[operation]
    start0 = np.asarray(op["die"]["profile_mm"], float)
    if "travel_mm" not in op:
        raise SystemExit(f"--operation {operation}: needs travel_mm (a shape is given at its end)")
    travel = float(start0[0, 1] - end[0, 1])
    if travel <= 0.0:
        raise SystemExit(
            f"--shape: its axis point z = {end[0, 1]:g} mm is not below the die's start "
            f"{start0[0, 1]:g} mm"
        )
    op["travel_mm"] = travel
    op["die"]["profile_mm"] = [[float(r), float(z + travel)] for r, z in end]
    for name, dz in raises.items():
        lifted = ops[name]
        lifted["die"]["profile_mm"] = [[r, z + dz] for r, z in lifted["die"]["profile_mm"]]
        if "travel_mm" in lifted:
            lifted["travel_mm"] = float(lifted["travel_mm"]) + dz
    return new


def plot(shapes: dict[str, np.ndarray], doc: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 3.5))
    last = [op for op in doc["process"]["operation"] if op["kind"] == "forming"][-1]
    prof = np.asarray(last["die"]["profile_mm"], float)
    if "final_gap_mm" in last:  # its end: the lowest point at half the final gap
        prof[:, 1] -= prof[:, 1].min() - 0.5 * float(last["final_gap_mm"])
    elif "travel_mm" in last:
        prof[:, 1] -= float(last["travel_mm"])
    ax.plot(prof[:, 0], prof[:, 1], "k-", lw=2, label=f"{last.get('name', 'last')} (end)")
    for name, xy in shapes.items():
        ax.plot(xy[:, 0], xy[:, 1], "-", label=name)
    ax.set_xlabel("r (mm)")
    ax.set_ylabel("z (mm)")
    ax.set_aspect("equal")
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5))
    fig.tight_layout()
    fig.savefig(out / "profiles.png", dpi=120)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("config")
    ap.add_argument("--shape", action="append", default=[], help="NAME='r,z;...' at its end")
    ap.add_argument("--operation", default="blocker")
    ap.add_argument("--raise", action="append", default=[], dest="raises", help="OPERATION=mm")
    ap.add_argument("--scales", default="0.945")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--set", action="append", default=[], dest="overrides")
    ap.add_argument("--out", default="out/blocker_trials")
    ap.add_argument("--timeout", type=float, default=3600.0, help="per run (s)")
    args = ap.parse_args(argv)
    with open(args.config, "rb") as fh:
        doc = tomllib.load(fh)
    doc.pop("design", None)
    ops = operations(doc)
    if args.operation not in ops:
        raise SystemExit(f"--operation {args.operation}: the process has {', '.join(ops)}")
    raises = {}
    for text in args.raises:
        name, _, dz = text.partition("=")
        if name not in ops:
            raise SystemExit(f"--raise {text}: the process has {', '.join(ops)}")
        raises[name] = float(dz)
    start = np.asarray(ops[args.operation]["die"]["profile_mm"], float)
    shapes = {"configured": start - [0.0, float(ops[args.operation].get("travel_mm", 0.0))]}
    shapes.update(parse_shape(s) for s in args.shape)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    plot(shapes, doc, out)
    jobs = []
    for name, end in shapes.items():
        folder = out / name
        folder.mkdir(exist_ok=True)
        config = folder / "config.toml"
        config.write_text(tomli_w.dumps(with_shape(doc, args.operation, end, raises)))
        jobs += [(name, config, float(s), folder) for s in args.scales.split(",")]

    def one(job):
        name, config, scale, folder = job
        row = run_scale(config, scale, folder, args.overrides, args.timeout)
        fill, flash = row.get("die_fill", float("nan")), row.get("flash_volume_mm3", float("nan"))
        print(f"{name} at scale {scale:g}: {row['status']}, fill {fill:.5f}, flash {flash:.2f} "
              f"mm^3, {row['wall_s']} s {row['message']}", flush=True)  # fmt: skip
        return {"shape": name, **row}

    with ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        rows = list(pool.map(one, jobs))
    with open(out / "trials.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, ("shape", *COLUMNS), extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
