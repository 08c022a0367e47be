"""Press tonnage against the time step and the mesh: the end force and the dips after remeshes.

Runs one config (default: the shipped closed die with flash) once per combination of time
step and remesh element size, each as its own ``jaxform run`` process (a crash or a hang
of one run cannot take the others with it), and tabulates per run the end force, the
remeshes, the steps, the Newton iterations per step and the dips: the force of the first
step after each remesh against the remeshing step's (in per cent; a negative dip is a
drop).  The dips are split at ``--flash-mm`` of stroke (where the flash starts under the
land).  The spread of the end force over the runs that finished is the convergence figure
of issue 38 item 4 (target: 2 %).

    python experiments/tonnage_convergence.py [CONFIG] --dt 1,0.5,0.25 --size 0.35,0.25
        [--set remesh.from_start=true ...] [--jobs 2] [--out out/tonnage]

writes ``results.csv`` and ``table.md`` into ``--out``; a run whose folder already has a
finished ``history.csv`` is read, not run again (``--rerun`` runs it anyway).
"""

from __future__ import annotations

import argparse
import csv
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

COLUMNS = ("dt_s", "element_size_mm", "status", "end_stroke_mm", "end_force_N", "remeshes",
           "steps", "newton_per_step", "worst_dip_before_pct", "worst_dip_flash_pct",
           "die_fill", "flash_volume_mm3", "wall_s")  # fmt: skip


def numbers(text: str) -> list[float]:
    return [float(v) for v in text.split(",") if v.strip()]


def dips(rows: list[dict]) -> list[tuple[float, float]]:
    """(stroke of the remesh, dip in per cent) for each remesh that a step follows."""
    force = np.array([float(r["force_N"]) for r in rows])
    out = []
    for i, r in enumerate(rows[:-1]):
        if r.get("remeshed", "0") not in ("", "0", "False") and force[i] > 0.0:
            out.append((float(r["stroke_mm"]), float(100.0 * (force[i + 1] / force[i] - 1.0))))
    return out


def summary(folder: Path, flash_mm: float) -> dict:
    """The row of results.csv of one finished (or stopped) run's folder."""
    with open(folder / "history.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    if not rows:
        return {}
    last = rows[-1]
    d = dips(rows)
    before = [v for s, v in d if s < flash_mm]
    flash = [v for s, v in d if s >= flash_mm]
    iters = [float(r["newton_iterations"]) for r in rows[1:]]
    return dict(
        end_stroke_mm=float(last["stroke_mm"]),
        end_force_N=float(last["force_N"]),
        remeshes=len(d) + (last.get("remeshed", "0") not in ("", "0", "False")),
        steps=len(rows) - 1,
        newton_per_step=float(np.mean(iters)) if iters else 0.0,
        worst_dip_before_pct=float(min(before, default=0.0)),
        worst_dip_flash_pct=float(min(flash, default=0.0)),
        die_fill=float(last.get("die_fill") or "nan"),
        flash_volume_mm3=float(last.get("flash_volume_mm3") or "nan"),
    )


def run_one(config: str, dt: float, size: float, args) -> dict:
    folder = Path(args.out) / f"dt{dt:g}_h{size:g}"
    folder.mkdir(parents=True, exist_ok=True)
    row = dict(dt_s=dt, element_size_mm=size)
    done = folder / "done"
    if done.exists() and not args.rerun:
        row.update(status=done.read_text().strip(), wall_s=float("nan"))
    else:
        cmd = [sys.executable, "-m", "jaxform.cli", "run", config, "--out", str(folder)]
        cmd += ["--set", f"time.dt_s={dt:g}", "--set", f"remesh.element_size_mm={size:g}"]
        for o in args.set:
            cmd += ["--set", o]
        t0 = time.perf_counter()
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=args.timeout)
            status = {0: "finished", 1: "stopped"}.get(proc.returncode, "crashed")
            if status != "finished":
                status += ": " + (proc.stderr.strip().splitlines() or [""])[-1][:160]
        except subprocess.TimeoutExpired:
            status = f"crashed: over {args.timeout:g} s"
        row["wall_s"] = time.perf_counter() - t0
        row["status"] = status
        done.write_text(status + "\n")
    if (folder / "history.csv").exists():
        row.update(summary(folder, args.flash_mm))
    print(", ".join(f"{k}={row.get(k, '')}" for k in COLUMNS), flush=True)
    return row


def table(rows: list[dict]) -> str:
    head = (
        "| dt (s) | element (mm) | end force (N) | remeshes | steps | Newton / step "
        "| worst dip before the flash | worst dip in the flash | fill | flash (mm^3) |"
    )
    lines = [head, "|" + "---|" * 10]
    for r in rows:
        if "end_force_N" not in r:
            lines.append(f"| {r['dt_s']:g} | {r['element_size_mm']:g} | {r['status']} |||||||")
            continue
        end = f"{r['end_force_N']:.0f}"
        if not str(r["status"]).startswith("finished"):
            end += f" (stopped at {r['end_stroke_mm']:.2f} mm)"
        lines.append(
            f"| {r['dt_s']:g} | {r['element_size_mm']:g} | {end} | {r['remeshes']} | {r['steps']} "
            f"| {r['newton_per_step']:.1f} | {r['worst_dip_before_pct']:+.1f} % "
            f"| {r['worst_dip_flash_pct']:+.1f} % | {100 * r['die_fill']:.3f} % "
            f"| {r['flash_volume_mm3']:.2f} |"
        )
    ends = [r["end_force_N"] for r in rows if str(r.get("status", "")).startswith("finished")]
    if len(ends) > 1:
        lines.append("")
        lines.append(f"End force over the finished runs: {min(ends):.0f} - {max(ends):.0f} N, "
                     f"spread {100 * (max(ends) / min(ends) - 1):.1f} % of the least.")  # fmt: skip
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("config", nargs="?", default="configs/closed_die_flash.toml")
    p.add_argument("--dt", default="1,0.5,0.25", help="time steps (s), comma separated")
    p.add_argument("--size", default="0.35,0.25", help="remesh element sizes (mm)")
    p.add_argument("--set", action="append", default=[], help="a config override, as jaxform's")
    p.add_argument("--flash-mm", type=float, default=4.25,
                   help="stroke (mm) from which a dip counts as in the flash")  # fmt: skip
    p.add_argument("--jobs", type=int, default=1)
    p.add_argument("--timeout", type=float, default=5400.0, help="per run (s)")
    p.add_argument("--rerun", action="store_true")
    p.add_argument("--out", default="out/tonnage")
    args = p.parse_args(argv)
    combos = [(dt, h) for h in numbers(args.size) for dt in numbers(args.dt)]
    with ThreadPoolExecutor(max_workers=args.jobs) as pool:
        rows = list(pool.map(lambda c: run_one(args.config, c[0], c[1], args), combos))
    out = Path(args.out)
    with open(out / "results.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=COLUMNS, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    text = table(rows)
    (out / "table.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
