"""Throughput of jaxform study: samples per minute for a loop of single runs, 1 and 2 local
worker processes and the batched path, and the inputs of a cost model for many machines.

    python experiments/bench_study.py --quick     # the 3 x 3 seed scene, 8 samples
    python experiments/bench_study.py             # the hot upsetting scene, 16 samples

Each mode runs the same Latin-hypercube samples (friction factor, ram speed; the quick
scene has shear friction 0.3 added):

* ``loop``: jaxform.driver.run of each sample in this process, one after another (what
  a shell loop over ``jaxform run`` gives, without its process starts);
* ``workers=1``, ``workers=2``: jaxform.study.engine.run_study on a new local Dask
  cluster, from cluster start to the last row;
* ``batched``: the same with study.batch = the sample count / 2 on 1 worker (the
  fixed-schedule model: see jaxform/study/batched.py);
* ``loop-warm``: the loop again, its programs now in this process and the cache.

The compilation cache starts empty: ``loop`` compiles, the worker modes load its programs
from the cache (their first sample is a cache load, not a compile), ``batched`` compiles
its own programs.

The cost model's inputs, measured here: per worker the first sample's time (cold: an empty
compilation cache, warm: the cache filled by the earlier modes), the median time of the
other samples, and the scheduler's overhead per task (no-op tasks through the same kind of
cluster).  Output: a table on stdout and ``bench_study.csv`` in --out.
"""

from __future__ import annotations

import argparse
import csv
import logging
import os
import statistics
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
QUICK = ["mesh.nr=3", "mesh.nz=3", "die.reduction=0.1", "time.dt_s=2.5",
         'friction.model="shear"', "friction.m=0.3"]  # fmt: skip
COMMON = ["output.fields=false", "output.plots=false", 'study.plan="latin_hypercube"',
          'study.responses=["force_N:max", "friction_work_Nmm:end"]', "study.seed=7"]  # fmt: skip


def _scene(quick: bool, samples: int) -> tuple[str, list[str]]:
    if quick:
        inputs = '["friction.m = uniform(0.1, 0.5)", "die.speed_mm_s = uniform(0.06, 0.15)"]'
        config, base = str(ROOT / "configs" / "upsetting_seed.toml"), QUICK
    else:
        inputs = '["friction.m = uniform(0.2, 0.5)", "die.speed_mm_s = uniform(5.0, 10.0)"]'
        config, base = str(ROOT / "configs" / "hot_upsetting.toml"), []
    return config, [*base, *COMMON, f"study.inputs={inputs}", f"study.samples={samples}"]


def _loop(study, config, sets) -> dict:
    from jaxform.driver import run
    from jaxform.study.engine import response_values

    times = []
    t0 = time.perf_counter()
    for i in range(study.n):
        t = time.perf_counter()
        response_values(run(config, [*sets, *study.overrides(i)]), study.responses)
        times.append(time.perf_counter() - t)
    return dict(wall_s=time.perf_counter() - t0, first_s=times[0],
                sample_s=statistics.median(times[1:]) if len(times) > 1 else times[0])  # fmt: skip


def _study(study, config, sets, workers: int, out: Path) -> dict:
    from jaxform.study.engine import RESULTS, Where, read_table, run_study

    t0 = time.perf_counter()
    run_study(study, config, sets, out, Where(workers=workers))
    wall = time.perf_counter() - t0
    rows = read_table(out / RESULTS)
    by_worker: dict[str, list[float]] = {}
    for r in rows:  # in the order they finished
        by_worker.setdefault(r["worker"], []).append(float(r["wall_s"]))
    firsts = [v[0] for v in by_worker.values()]
    rest = [t for v in by_worker.values() for t in v[1:]] or firsts
    return dict(wall_s=wall, first_s=max(firsts), sample_s=statistics.median(rest),
                failed=sum(r["status"] != "ok" for r in rows))  # fmt: skip


def _overhead(n_tasks: int = 200) -> float:
    """Seconds of scheduling per task: no-op tasks on a 1-worker local cluster."""
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                      dashboard_address=":0", silence_logs=logging.ERROR) as cluster:  # fmt: skip
        with Client(cluster) as client:
            client.submit(os.getpid, pure=False).result()  # the worker is up
            t0 = time.perf_counter()
            futures = [
                client.submit(os.getpid, key=f"noop-{i}", pure=False) for i in range(n_tasks)
            ]
            client.gather(futures)
            return (time.perf_counter() - t0) / n_tasks


def main(argv=None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="the 3 x 3 seed scene, 8 samples")
    ap.add_argument("--samples", type=int, default=None)
    ap.add_argument("--out", default="out/bench_study")
    ap.add_argument("--modes", nargs="+",
                    default=["loop", "workers=1", "workers=2", "batched", "loop-warm"])  # fmt: skip
    args = ap.parse_args(argv)
    from jaxform.precision import enable_x64
    from jaxform.study.spec import build_study

    enable_x64()
    n = args.samples or (8 if args.quick else 16)
    config, sets = _scene(args.quick, n)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    # cold compiles: an empty compilation cache for this process and its workers
    cache = tempfile.mkdtemp(prefix="bench_study_cache_")
    os.environ["JAXFORM_CACHE_DIR"] = cache
    from jaxform.cache import enable_compilation_cache

    enable_compilation_cache(cache)
    results = []
    for mode in args.modes:
        s = [*sets, f"study.batch={max(1, n // 2)}"] if mode == "batched" else sets
        study = build_study(config, s)
        folder = Path(tempfile.mkdtemp(prefix=f"bench_{mode.replace('=', '')}_", dir=out))
        if mode.startswith("loop"):  # loop: the first compiles; loop-warm: from the cache
            r = _loop(study, config, s)
        else:
            workers = 1 if mode in ("workers=1", "batched") else int(mode.split("=")[1])
            r = _study(study, config, s, workers, folder)
        r.update(mode=mode, samples=n, per_min=60.0 * n / r["wall_s"])
        results.append(r)
        print(
            f"{mode:>10}: {n} samples in {r['wall_s']:.1f} s = {r['per_min']:.2f} samples/min; "
            f"first sample {r['first_s']:.1f} s, then {r['sample_s']:.3f} s each",
            flush=True,
        )
    per_task = _overhead()
    print(f"scheduler overhead: {1e3 * per_task:.2f} ms per task (no-op tasks, 1 local worker)")
    results.append(dict(mode="scheduler_overhead", samples=200, wall_s=per_task))
    cols = ["mode", "samples", "wall_s", "per_min", "first_s", "sample_s", "failed"]
    with open(out / "bench_study.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=cols, extrasaction="ignore")
        w.writeheader()
        w.writerows(results)
    return results


if __name__ == "__main__":
    main()
