"""Closed dies nobody tuned: run generated flanged-hub forgings with the library's defaults.

Each seed (:mod:`jaxform.generated_dies`) runs in its own process (``jaxform run`` with
the config written to ``--out``/seed_<k>/config.toml) with a wall-clock limit, so a crash
or a hang of one die cannot take the others with it.  A run counts as *finished* when it
reaches the end of its stroke, *stopped* when jaxform ended it with its one-line message
(exit 1), *crashed* on anything else (a traceback, a signal, the time limit).

    python experiments/generated_dies.py --seeds 0-29 [--set remesh.quality_below=0.3]
        [--timeout 1800] [--out out/generated_dies]

writes ``results.csv`` (one row per seed: status, steps, stroke, force, fill, remeshes,
Newton iterations, cutbacks, wall time, the last line of stderr) and prints the completion
rate; ``--quick`` runs seeds 0-1 on a 6 x 6 mesh (the test suite's smoke check of this
script).
"""

from __future__ import annotations

import argparse
import csv
import subprocess
import sys
import time
from pathlib import Path

from jaxform.config import dump_config
from jaxform.generated_dies import draw, flanged_hub

COLUMNS = ("seed", "status", "steps", "stroke_mm", "force_N", "die_fill", "remeshes",
           "newton_iterations", "cutbacks", "wall_s", "message", "dies")  # fmt: skip


def seeds(text: str) -> list[int]:
    """'0-9,12' -> [0, ..., 9, 12]."""
    out = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        out += list(range(int(a), int(b or a) + 1))
    return out


def summary(history: Path) -> dict:
    """The run's end (stroke, force, fill) and its totals (steps, remeshes, Newton
    iterations, cutbacks) from its history.csv."""
    with open(history, newline="") as fh:
        rows = list(csv.DictReader(fh))
    if not rows:
        return {}

    def total(key):
        return sum(int(float(r.get(key, 0) or 0)) for r in rows)

    last = rows[-1]
    return dict(steps=len(rows) - 1, stroke_mm=last.get("stroke_mm", ""),
                force_N=last.get("force_N", ""), die_fill=last.get("die_fill", ""),
                remeshes=total("remeshed"), newton_iterations=total("newton_iterations"),
                cutbacks=total("cutbacks"))  # fmt: skip


def run_seed(seed: int, out: Path, overrides: list[str], timeout: float) -> dict:
    """Run forging ``seed`` in a subprocess; its row of results.csv."""
    folder = out / f"seed_{seed}"
    folder.mkdir(parents=True, exist_ok=True)
    dump_config(flanged_hub(seed), folder / "config.toml")
    cmd = [sys.executable, "-m", "jaxform.cli", "run", str(folder / "config.toml"),
           "--out", str(folder)]  # fmt: skip
    for o in overrides:
        cmd += ["--set", o]
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        code, err = proc.returncode, proc.stderr
    except subprocess.TimeoutExpired as exc:
        code, err = None, f"time limit {timeout:g} s reached; {exc.stderr or ''}"
    wall = time.perf_counter() - t0
    lines = [ln for ln in (err or "").splitlines() if ln.strip() and "slow_operation" not in ln]
    traceback = any(ln.startswith("Traceback") for ln in lines)
    status = {0: "finished", 1: "stopped"}.get(code, "crashed")
    if traceback:
        status = "crashed"
    row = dict(seed=seed, status=status, wall_s=round(wall, 1), dies=str(draw(seed)),
               message=(lines[-1] if lines and code != 0 else "")[:400])  # fmt: skip
    history = folder / "history.csv"
    if history.exists():
        row.update(summary(history))
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0-29")
    ap.add_argument("--set", action="append", default=[], help="override for every run")
    ap.add_argument("--timeout", type=float, default=1800.0, help="per run (s)")
    ap.add_argument("--out", default="out/generated_dies")
    ap.add_argument("--quick", action="store_true", help="seeds 0-1 on a 6 x 6 mesh")
    args = ap.parse_args(argv)
    chosen, over = seeds(args.seeds), list(args.set)
    if args.quick:
        chosen, over = [0, 1], over + ["mesh.nr=6", "mesh.nz=6", "output.plots=false"]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    table = out / "results.csv"
    with open(table, "w", newline="") as fh:
        writer = csv.DictWriter(fh, COLUMNS)
        writer.writeheader()
        counts = {"finished": 0, "stopped": 0, "crashed": 0}
        for k in chosen:
            row = run_seed(k, out, over, args.timeout)
            writer.writerow({c: row.get(c, "") for c in COLUMNS})
            fh.flush()
            counts[row["status"]] += 1
            print(f"seed {k}: {row['status']} stroke {row.get('stroke_mm', '-')} mm, fill "
                  f"{row.get('die_fill', '-')}, {row.get('remeshes', '-')} remeshes, "
                  f"{row['wall_s']} s {row['message']}", flush=True)  # fmt: skip
    n = len(chosen)
    print(
        f"{counts['finished']}/{n} finished ({100.0 * counts['finished'] / n:.0f} %), "
        f"{counts['stopped']} stopped with a message, {counts['crashed']} crashed -> {table}"
    )
    return 0 if counts["crashed"] == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
