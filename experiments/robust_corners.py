"""A process design over the range of its uncertain inputs: the friction factor and the
die temperature at the corners and the middle of their ranges, each a whole run.

A design of least flash stops where the finisher just fills at the inputs it was designed
for; whether it fills as the shop's friction and die temperature drift is read by running
it there.  This runs a process config (``jaxform run``, each in its own process, with
``experiments/billet_volume_sweep.py``'s runner) at every pair of ``--friction`` (the
shear factor m of every die, ``friction.m``) and ``--die-temperature``
(``thermal.die_temperature_K``), and prints the table of finisher fill / flash / peak
forces (issue 39: the nominal against the robust design).

    python experiments/robust_corners.py CONFIG [--friction 0.2,0.3,0.4]
        [--die-temperature 423,473,523] [--jobs 1] [--set section.key=value ...]
        [--out out/robust_corners] [--fill 0.999]

writes ``corners.csv`` (one row per pair: the last forming operation's die fill and flash,
each blow's peak force, laps, pockets; a run that stops: its one line) and each run in
``m<m>_T<T>/``.
"""

from __future__ import annotations

import argparse
import csv
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from billet_volume_sweep import COLUMNS, run_scale

FIELDS = ("friction_m", "die_temperature_K", *COLUMNS)


def run_corner(config: Path, m: float, temp: float, out: Path, overrides, timeout) -> dict:
    sets = [*overrides, f"friction.m={m!r}", f"thermal.die_temperature_K={temp!r}"]
    row = run_scale(config, 1.0, out / f"m{m:g}_T{temp:g}", sets, timeout)
    return {"friction_m": m, "die_temperature_K": temp, **row}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("config")
    ap.add_argument("--friction", default="0.2,0.3,0.4")
    ap.add_argument("--die-temperature", default="423,473,523")
    ap.add_argument("--fill", type=float, default=0.999, help="the fill a design must reach")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--set", action="append", default=[], dest="overrides")
    ap.add_argument("--out", default="out/robust_corners")
    ap.add_argument("--timeout", type=float, default=3600.0, help="per run (s)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    pairs = [(float(m), float(t)) for m in args.friction.split(",")
             for t in args.die_temperature.split(",")]  # fmt: skip
    with ThreadPoolExecutor(args.jobs) as pool:
        rows = list(pool.map(lambda p: run_corner(Path(args.config), *p, out, args.overrides,
                                                  args.timeout), pairs))  # fmt: skip
    with open(out / "corners.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, FIELDS, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    temps = sorted({t for _, t in pairs})
    print("fill / flash (mm^3) / peak forces (kN); friction m down, die temperature (K) across")
    print("| m \\ dies | " + " | ".join(f"{t:g} K" for t in temps) + " |")
    print("|---" * (len(temps) + 1) + "|")
    for m in sorted({m for m, _ in pairs}):
        cells = []
        for t in temps:
            r = next(r for r in rows if r["friction_m"] == m and r["die_temperature_K"] == t)
            if r["status"] != "finished":
                cells.append(f"{r['status']}: {r['message'][:60]}")
                continue
            kn = "/".join(f"{float(p) / 1e3:.1f}" for p in r["peak_forces_N"].split())
            cells.append(f"{r['die_fill']:.5f} / {r['flash_volume_mm3']:.2f} / {kn}")
        print(f"| {m:g} | " + " | ".join(cells) + " |")
    filled = sum(r["status"] == "finished" and r["die_fill"] >= args.fill for r in rows)
    print(f"fills to {args.fill:g} at {filled} of {len(rows)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
