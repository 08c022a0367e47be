"""Time to first result: where a fresh process spends its time, cold and warm.

    python experiments/bench_startup.py [--programs seed friction gradient design
                                         seed-modified] [--quick] [--csv out.csv]

Each program runs in a fresh process twice: cold (an empty compilation cache directory)
and warm (a second process on the cache the first filled).  Its time is split into

* process: the whole process, wall clock (interpreter start to exit);
* import: ``import jax`` and the jaxform modules the program uses;
* trace / lower / compile: JAX's own events (``/jax/core/compile/...``) for every program
  compiled in the process (the main one and the small ones around it), each phase as
  the union of its time spans (nested traces are not counted twice);
* load: reading compiled programs from the cache (``/jax/compilation_cache/
  cache_retrieval_time_sec``; JAX counts it inside its compile event, taken out of
  compile here);
* run: the rest of the call (running the programs, Python around them);

and the compile/load of the main program alone (the one that took longest to compile or
load), with the number of programs loaded from the cache and compiled.

Programs: ``seed`` (``jaxform.driver.run`` of configs/upsetting_seed.toml, full Newton
with klujax), ``seed-modified`` (the same with modified Newton: its load-step chunk frees
factorizations through a host callback), ``friction`` (configs/upsetting_friction.toml),
``gradient`` (value and gradient of the 10 x 10 seed with respect to every design group,
as experiments/bench_gradient.py), ``design`` (``jaxform.driver.run_design`` of
configs/preform_design.toml).  ``--quick``: seed only, and two design iterations.
Writes a CSV (default out/bench_startup.csv) and prints a markdown table.  Timings on a
shared machine are noisy: compare cold and warm of one program, not across runs.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PROGRAMS = ("seed", "friction", "gradient", "design", "seed-modified")
NO_OUTPUT = ["output.fields=false", "output.plots=false"]
PHASES = ("trace", "lower", "compile", "load")
COLUMNS = (
    "program",
    "cache",
    "process_s",
    "import_s",
    "trace_s",
    "lower_s",
    "compile_s",
    "load_s",
    "run_s",
    "main",
    "main_compile_s",
    "main_load_s",
    "hits",
    "compiled",
)


def _union(spans) -> float:
    total, end = 0.0, -float("inf")
    for a, b in sorted(spans):
        if b > end:
            total += b - max(a, end)
            end = b
    return total


def child(program: str, quick: bool) -> dict:
    """Run one program in this (fresh) process; the phases as a dict."""
    t0 = time.perf_counter()
    import jax

    import jaxform
    from jaxform.cache import enable_compilation_cache

    events = {
        "/jax/core/compile/jaxpr_trace_duration": "trace",
        "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
        "/jax/core/compile/backend_compile_duration": "compile",
    }
    spans = {p: [] for p in PHASES}
    per_program = {}  # module name -> [compile incl. load, load]
    counts = {"hits": 0, "requests": 0, "load": 0.0, "pending": 0.0}

    def on_span(event, start, end, **kw):
        if event in events:
            spans[events[event]].append((start, end))
            if events[event] == "compile":
                entry = per_program.setdefault(kw.get("fun_name", "?"), [0.0, 0.0])
                entry[0] += end - start
                entry[1] += counts["pending"]
                counts["pending"] = 0.0

    def on_duration(event, duration, **kw):
        if event == "/jax/compilation_cache/cache_retrieval_time_sec":
            counts["load"] += duration
            counts["pending"] = duration

    def on_event(event, **kw):  # JAX's "cache_misses" counts entries written, not misses
        if event == "/jax/compilation_cache/cache_hits":
            counts["hits"] += 1
        elif event == "/jax/compilation_cache/compile_requests_use_cache":
            counts["requests"] += 1

    jax.monitoring.register_event_time_span_listener(on_span)
    jax.monitoring.register_event_duration_secs_listener(on_duration)
    jax.monitoring.register_event_listener(on_event)
    if program in ("seed", "seed-modified", "friction"):
        from jaxform.driver import run
    elif program == "gradient":
        from jaxform.config import load_config
        from jaxform.design import available_groups, build_problem
        from jaxform.scenes import build_scene
    else:
        from jaxform.driver import run_design
    t_import = time.perf_counter() - t0
    jaxform.enable_x64()
    enable_compilation_cache()  # the directory from JAXFORM_CACHE_DIR (set by the parent)
    t1 = time.perf_counter()
    if program in ("seed", "seed-modified", "friction"):
        config = "upsetting_friction" if program == "friction" else "upsetting_seed"
        extra = (
            ["solver.newton=modified", "solver.linear=sparse"] if program == "seed-modified" else []
        )
        run(ROOT / "configs" / f"{config}.toml", NO_OUTPUT + extra)
    elif program == "gradient":
        scene = build_scene(load_config(ROOT / "configs/upsetting_seed.toml", NO_OUTPUT))
        problem = build_problem(scene, groups=available_groups(scene))
        jax.block_until_ready(problem.value_and_grad(problem.start)[1])
    else:
        with tempfile.TemporaryDirectory() as out:
            run_design(
                ROOT / "configs/preform_design.toml",
                ["design.iterations=2"] if quick else [],
                out_dir=out,
            )
    call = time.perf_counter() - t1
    phase = {p: _union(spans[p]) for p in PHASES}
    phase["load"] = counts["load"]
    phase["compile"] -= counts["load"]
    # trace spans of jit calls made while tracing lie inside the outer trace; compile of
    # inner programs (eager ops while tracing) is rare: the phases are disjoint enough
    run_s = call - sum(phase.values())
    # the main program: the one that took longest to compile or load
    name, (c, ld) = max(per_program.items(), key=lambda kv: kv[1][0])
    return dict(
        import_s=t_import,
        **{f"{p}_s": phase[p] for p in PHASES},
        run_s=run_s,
        main=name,
        main_compile_s=c - ld,
        main_load_s=ld,
        hits=counts["hits"],
        compiled=counts["requests"] - counts["hits"],
    )


def measure(program: str, cache_dir: Path, quick: bool) -> dict:
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("JAX_COMPILATION_CACHE_DIR", "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS")
    }
    env["JAXFORM_CACHE_DIR"] = str(cache_dir)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    cmd = [sys.executable, __file__, "--child", program] + (["--quick"] if quick else [])
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, cwd=ROOT, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"{program}: the child process failed:\n{proc.stderr[-3000:]}")
    line = [s for s in proc.stdout.splitlines() if s.startswith("RESULT ")][-1]
    return dict(json.loads(line[len("RESULT ") :]), process_s=wall)


def table(rows) -> str:
    head = (
        "| program | cache | process (s) | import (s) | trace (s) | lower (s) | "
        "compile (s) | load (s) | run (s) | main program compile / load (s) | "
        "loaded / compiled |"
    )
    lines = [head, "|" + "---|" * 11]
    for r in rows:
        lines.append(
            f"| {r['program']} | {r['cache']} | {r['process_s']:.1f} | {r['import_s']:.1f} | "
            f"{r['trace_s']:.1f} | {r['lower_s']:.1f} | {r['compile_s']:.1f} | "
            f"{r['load_s']:.2f} | {r['run_s']:.1f} | {r['main_compile_s']:.1f} / "
            f"{r['main_load_s']:.2f} ({r['main']}) | {r['hits']} / {r['compiled']} |"
        )
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--programs",
        nargs="+",
        choices=PROGRAMS,
        default=None,
        help=f"default: all ({', '.join(PROGRAMS)}); seed with --quick",
    )
    ap.add_argument(
        "--quick",
        action="store_true",
        help="seed only (unless --programs), design with two iterations",
    )
    ap.add_argument("--csv", default=str(ROOT / "out" / "bench_startup.csv"))
    ap.add_argument("--child", choices=PROGRAMS, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print("RESULT " + json.dumps(child(args.child, args.quick)), flush=True)
        return
    programs = args.programs or (["seed"] if args.quick else list(PROGRAMS))
    rows = []
    for program in programs:
        with tempfile.TemporaryDirectory(prefix="jaxform-bench-cache-") as cache:
            for mode in ("cold", "warm"):
                r = dict(measure(program, Path(cache), args.quick), program=program, cache=mode)
                rows.append(r)
                print(f"{program} {mode}: {r['process_s']:.1f} s", flush=True)
    out = Path(args.csv)
    out.parent.mkdir(parents=True, exist_ok=True)
    with out.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS)
        w.writeheader()
        for r in rows:
            w.writerow({k: (round(r[k], 4) if isinstance(r[k], float) else r[k]) for k in COLUMNS})
    print("\n" + table(rows))
    print(f"\nwrote {out}")


if __name__ == "__main__":
    main()
