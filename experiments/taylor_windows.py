"""The default Taylor test on every shipped design scene: which window each group found,
which steps it skipped (another contact active set, or a run that did not converge), its
smallest second-order rate, and the wall time, as a markdown table and a CSV.

    python experiments/taylor_windows.py [--only NAME ...] [--out docs/figures/taylor_windows.csv]

Each scene runs ``jaxform taylor-test CONFIG`` as a user would (default steps h = 1 .. 1/8,
every design group the scene has), in this process one after another; the wall time
includes compilation.  A scene passes when every group's smallest rate is >= 1.9.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

SCENES = {
    "seed": "configs/upsetting_seed.toml",
    "friction": "configs/upsetting_friction.toml",
    "ring": "configs/ring_compression.toml",
    "preform": "configs/preform_design.toml",
}


def run(name: str) -> list[dict]:
    from jaxform.driver import run_taylor

    t0 = time.perf_counter()
    rows = run_taylor(SCENES[name], progress=_trace)
    wall = time.perf_counter() - t0
    return [
        dict(
            scene=name,
            group=r.group,
            window=(f"{r.h[0]:g}..{r.h[-1]:g}" if len(r.h) else "none")
            + (" along -du" if r.sign < 0 else ""),
            skipped=" ".join(f"{v:g}" for v in r.skipped) or "-",
            min_rate=r.min_rate,
            passed=bool(r.min_rate >= 1.9),
            wall_s=wall,
        )
        for r in rows
    ]


def _trace(group: str, h: float, j: float) -> None:
    print(f"  {group}: h = {h:g}, J = {j:.12g}", flush=True)


def main() -> None:
    import jaxform

    jaxform.enable_x64()
    jaxform.enable_compilation_cache()
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="*", choices=sorted(SCENES), default=None)
    ap.add_argument("--out", default="docs/figures/taylor_windows.csv")
    args = ap.parse_args()
    table = []
    for name in args.only or SCENES:
        rows = run(name)
        table += rows
        for r in rows:
            print(f"{name}: {r}", flush=True)
    print("| scene | group | window h | skipped h | min rate | pass |")
    print("|---|---|---|---|---|---|")
    for r in table:
        rate = "noise" if np.isinf(r["min_rate"]) else f"{r['min_rate']:.2f}"
        print(f"| {r['scene']} | {r['group']} | {r['window']} | {r['skipped']} | {rate} | "
              f"{'yes' if r['passed'] else 'no'} |")  # fmt: skip
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    keys = list(table[0])
    lines = [",".join(keys)] + [",".join(str(r[k]) for k in keys) for r in table]
    out.write_text("\n".join(lines) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
