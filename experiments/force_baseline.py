"""Record or compare the history of every shipped scene: the refactoring guard.

    python experiments/force_baseline.py record DIR   # one .npz per config in configs/
    python experiments/force_baseline.py compare DIR  # max relative difference per column

A restructuring of the code must leave every shipped scene's force history unchanged
(to 1e-10 relative by default); `compare` exits 1 when a column moves more than --rtol.
Design and study configs run their forward scene (`jaxform run` on the same file).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SKIP = {"study_hot_upsetting.toml"}  # a study runs many samples; its scene is hot_upsetting


def _histories(names):
    import jax

    jax.config.update("jax_enable_x64", True)
    from jaxform.driver import run
    from jaxform.simulation import SimulationError

    for name in names:
        t0 = time.perf_counter()
        try:
            res = run(ROOT / "configs" / name)
            failure = ""
        except SimulationError as err:
            res, failure = err.result, str(err)
        hist = res.history if hasattr(res, "history") else res.history_table()
        cols = {k: np.asarray(v, dtype=float) for k, v in hist.items()
                if np.asarray(v).dtype.kind in "fiub"}  # fmt: skip
        print(f"{name}: {len(cols.get('time_s', []))} rows, {time.perf_counter() - t0:.1f} s"
              + (f" (stopped: {failure})" if failure else ""), flush=True)  # fmt: skip
        yield name, cols


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mode", choices=("record", "compare"))
    ap.add_argument("dir")
    ap.add_argument("--rtol", type=float, default=1e-10)
    ap.add_argument("--only", nargs="*", default=None, help="config file names")
    a = ap.parse_args(argv)
    out = Path(a.dir)
    names = a.only or sorted(
        p.name for p in (ROOT / "configs").glob("*.toml") if p.name not in SKIP
    )
    bad = 0
    for name, cols in _histories(names):
        path = out / (name.removesuffix(".toml") + ".npz")
        if a.mode == "record":
            out.mkdir(parents=True, exist_ok=True)
            np.savez(path, **cols)
            continue
        ref = dict(np.load(path))
        for k in sorted(set(ref) | set(cols)):
            if k not in ref or k not in cols or ref[k].shape != cols[k].shape:
                old, new = ref.get(k, np.empty(0)), cols.get(k, np.empty(0))
                ends = f", last {old[-1]:.9g} -> {new[-1]:.9g}" if old.size and new.size else ""
                print(f"  {k}: shape {old.shape} -> {new.shape}{ends}")
                bad += 1
                continue
            scale = max(np.max(np.abs(ref[k])), 1e-300)
            d = float(np.max(np.abs(cols[k] - ref[k])) / scale) if ref[k].size else 0.0
            if d > a.rtol or k == "force_N":
                print(f"  {k}: max relative difference {d:.3g}")
            bad += d > a.rtol
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
