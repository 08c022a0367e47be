"""The naive family of a process: its dies as configured, only the billet's volume chosen.

A forging engineer without a die design picks the billet: the least volume whose finisher
still fills.  This runs a process config (``jaxform run``, each in its own process) with
the billet scaled in volume at its aspect (diameter and height times scale^(1/3)) and
reports, per run, the last forming operation's die fill and flash, each blow's peak force
and the laps and pockets the run reports; then the least-flash run that fills to
``--fill`` (the reference a die design is measured against, issue 39).

    python experiments/billet_volume_sweep.py CONFIG --scales 0.97,0.985,1,1.015
        [--fill 0.999] [--set section.key=value ...] [--out out/billet_volume_sweep]
        [--timeout 3600]

writes ``sweep.csv`` (one row per scale; a run that stops: its one-line message) and each
run's output in ``scale_<s>/`` (``run.log``: what it printed), and prints the table.
"""

from __future__ import annotations

import argparse
import csv
import math
import subprocess
import sys
import time
import tomllib
from pathlib import Path

COLUMNS = ("scale", "diameter_mm", "height_mm", "volume_mm3", "status", "die_fill",
           "flash_volume_mm3", "peak_forces_N", "laps", "pockets", "wall_s", "message")  # fmt: skip


def billet_of(config: Path) -> tuple[float, float]:
    """(diameter, height) of the config's billet (mm)."""
    with open(config, "rb") as fh:
        billet = tomllib.load(fh)["billet"]
    return float(billet["diameter_mm"]), float(billet["height_mm"])


def last_forming(folder: Path) -> tuple[int, list[float]]:
    """(the last operation that moved a die, every operation's peak force) from operations.csv."""
    with open(folder / "operations.csv", newline="") as fh:
        ops = list(csv.DictReader(fh))
    blows = [o for o in ops if int(o["steps"]) > 0 and float(o["stroke_mm"]) > 0]
    return int(blows[-1]["operation"]), [float(o["peak_force_N"]) for o in blows]


def end_of(folder: Path, operation: int) -> dict:
    """The last history row of ``operation``."""
    with open(folder / "history.csv", newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if int(float(r["operation"])) == operation]
    return rows[-1]


def run_scale(config: Path, scale: float, out: Path, overrides: list[str], timeout: float) -> dict:
    d0, h0 = billet_of(config)
    f = scale ** (1.0 / 3.0)
    d, h = d0 * f, h0 * f
    folder = out / f"scale_{scale:g}"
    cmd = [sys.executable, "-m", "jaxform.cli", "run", str(config), "--out", str(folder),
           "--set", f"billet.diameter_mm={d!r}", "--set", f"billet.height_mm={h!r}"]  # fmt: skip
    for o in overrides:
        cmd += ["--set", o]
    volume = 0.25 * math.pi * d * d * h
    row = {"scale": scale, "diameter_mm": d, "height_mm": h, "volume_mm3": volume}
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        code, out_text, err = proc.returncode, proc.stdout, proc.stderr
    except subprocess.TimeoutExpired:
        code, out_text, err = None, "", f"time limit {timeout:g} s"
    row["wall_s"] = round(time.perf_counter() - t0, 1)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "run.log").write_text(out_text + err)
    lines = out_text.splitlines()
    # each operation's laps and pockets to its end ("<operation>: lap: ..." in a process)
    row["laps"] = sum(1 for line in lines if "lap: from stroke" in line)
    row["pockets"] = sum(1 for line in lines if "pocket (underfill along the die)" in line)
    if code == 0:
        op, peaks = last_forming(folder)
        end = end_of(folder, op)
        row.update(status="finished", die_fill=float(end["die_fill"]),
                   flash_volume_mm3=float(end["flash_volume_mm3"]),
                   peak_forces_N=" ".join(f"{p:.0f}" for p in peaks), message="")  # fmt: skip
    else:
        said = [line for line in err.strip().splitlines() if "written to" not in line]
        status = {1: "stopped", 2: "refused"}.get(code, "crashed")
        row.update(status=status, message=(said or [""])[-1][:300])
    return row


def least_flash_filling(rows: list[dict], fill: float) -> dict | None:
    ok = [r for r in rows if r["status"] == "finished" and r["die_fill"] >= fill]
    return min(ok, key=lambda r: r["flash_volume_mm3"]) if ok else None


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("config")
    ap.add_argument("--scales", default="0.97,0.985,1,1.015,1.03")
    ap.add_argument("--fill", type=float, default=0.999, help="the fill a design must reach")
    ap.add_argument("--set", action="append", default=[], dest="overrides")
    ap.add_argument("--out", default="out/billet_volume_sweep")
    ap.add_argument("--timeout", type=float, default=3600.0, help="per run (s)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for s in (float(x) for x in args.scales.split(",")):
        row = run_scale(Path(args.config), s, out, args.overrides, args.timeout)
        rows.append(row)
        with open(out / "sweep.csv", "w", newline="") as fh:
            w = csv.DictWriter(fh, COLUMNS, extrasaction="ignore")
            w.writeheader()
            w.writerows(rows)
        print(f"scale {s:g} (volume {row['volume_mm3']:.2f} mm^3): {row['status']}, "
              f"fill {row.get('die_fill', float('nan')):.5f}, flash "
              f"{row.get('flash_volume_mm3', float('nan')):.2f} mm^3, peaks "
              f"{row.get('peak_forces_N', '-')} N, laps {row['laps']}, pockets {row['pockets']}, "
              f"{row['wall_s']} s {row['message']}", flush=True)  # fmt: skip
    best = least_flash_filling(rows, args.fill)
    if best is None:
        print(f"no run fills to {args.fill:g}")
    else:
        print(
            f"least flash filling to {args.fill:g}: scale {best['scale']:g}, "
            f"flash {best['flash_volume_mm3']:.2f} mm^3, fill {best['die_fill']:.5f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
