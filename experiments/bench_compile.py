"""Where a program's compile time goes: its size, and XLA's own phases.

    python experiments/bench_compile.py [--program chunk|gradient] [--set key=value ...]
                                        [--top 12] [--no-xla]

For the load-step chunk of configs/upsetting_seed.toml (``chunk``, the program a run
compiles first) or the value-and-gradient program of the 10 x 10 seed with every design
group (``gradient``), in this process, with the persistent cache off:

* the traced program's equations (nested sub-programs included), by jaxform module and by
  source line: which code makes the program big, and which functions are traced often;
* tracing and lowering time, and the StableHLO text size;
* XLA's compile, split from its profiler trace into HLO passes (the slowest passes by
  name), fused-kernel compilation and LLVM code generation (``--no-xla``: skipped).

``--set`` overrides keys of the seed scene (e.g. ``--set mesh.nr=40 --set mesh.nz=40``).
Compile times are one process's on a shared machine: compare programs or code versions
measured one after the other, not across days.  Numbers are in docs/benchmarks.md,
"Compile time".
"""

from __future__ import annotations

import argparse
import collections
import glob
import gzip
import json
import os
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
NO_OUTPUT = ["output.fields=false", "output.plots=false"]


def program(kind: str, overrides: list[str]):
    """(function, arguments) of the program to measure."""
    from jaxform.config import load_config
    from jaxform.scenes import build_scene

    scene = build_scene(load_config(ROOT / "configs/upsetting_seed.toml", NO_OUTPUT + overrides))
    if kind == "chunk":
        from jaxform.simulation import init
        from jaxform.stepping import run_chunk, stepper_of

        stepper = stepper_of(scene)
        state, control = init(scene)
        n = scene.model.layout.n_dofs
        fac = scene.newton.variant.factorization(scene.linear, n, state.x.dtype)

        def fn(s, c, i, x, f):
            return run_chunk(stepper, s, c, i, x, scene.chunk, f)

        return fn, (state, control, scene.inputs, scene.idx, fac)
    import jax

    from jaxform.design import available_groups, build_problem

    problem = build_problem(scene, groups=available_groups(scene))
    grad = jax.value_and_grad(lambda d, i: problem._j(d, i, True), has_aux=True)
    return grad, (problem.start, scene.idx)


def equations(closed_jaxpr):
    """Counter of equations by 'module.py:line function' (sub-programs included)."""
    import jax
    from jax._src import source_info_util

    counts = collections.Counter()

    def walk(jaxpr):
        for eqn in jaxpr.eqns:
            tb = eqn.source_info.traceback
            frame = source_info_util.user_frame(tb) if tb else None
            key = (
                f"{os.path.basename(frame.file_name)}:{frame.start_line} {frame.function_name}"
                if frame
                else "(inside jax)"
            )
            counts[key] += 1
            for p in eqn.params.values():
                for sub in p if isinstance(p, (list, tuple)) else (p,):
                    if isinstance(sub, jax.extend.core.ClosedJaxpr):
                        walk(sub.jaxpr)
                    elif isinstance(sub, jax.extend.core.Jaxpr):
                        walk(sub)

    walk(closed_jaxpr.jaxpr)
    return counts


def xla_phases(lowered, options) -> dict:
    """Compile ``lowered`` under JAX's profiler; seconds per XLA event name."""
    import jax

    with tempfile.TemporaryDirectory() as d:
        jax.profiler.start_trace(d, create_perfetto_trace=True)
        t0 = time.perf_counter()
        lowered.compile(compiler_options=options)
        wall = time.perf_counter() - t0
        jax.profiler.stop_trace()
        (path,) = glob.glob(f"{d}/plugins/profile/*/perfetto_trace.json.gz")
        with gzip.open(path) as fh:
            data = json.load(fh)
    events = data["traceEvents"] if isinstance(data, dict) else data
    total = collections.Counter()
    for e in events:
        if e.get("ph") == "X":
            total[e["name"]] += e.get("dur", 0) / 1e6
    total["(wall)"] = wall
    return total


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--program", choices=("chunk", "gradient"), default="chunk")
    ap.add_argument("--set", action="append", default=[], dest="overrides")
    ap.add_argument("--top", type=int, default=12)
    ap.add_argument("--no-xla", action="store_true")
    args = ap.parse_args(argv)
    os.environ["JAXFORM_CACHE_DIR"] = "off"
    os.environ["JAXFORM_PROGRAM_STORE"] = "off"
    import jax

    import jaxform
    from jaxform.xla_options import compiler_options

    jaxform.enable_x64()
    fn, fargs = program(args.program, args.overrides)
    t0 = time.perf_counter()
    traced = jax.jit(fn).trace(*fargs)
    t1 = time.perf_counter()
    lowered = traced.lower()
    t2 = time.perf_counter()
    text = lowered.as_text()
    counts = equations(traced.jaxpr)
    by_module = collections.Counter()
    for key, n in counts.items():
        by_module[key.split(":")[0]] += n
    print(f"program: {args.program} {' '.join(args.overrides)}")
    print(f"trace {t1 - t0:.2f} s, lower {t2 - t1:.2f} s; {sum(counts.values())} equations, "
          f"StableHLO {len(text) / 1e6:.2f} MB, {text.count(chr(10))} lines")  # fmt: skip
    print("equations by module: " + ", ".join(f"{k} {v}" for k, v in by_module.most_common()))
    print("equations by source line:")
    for key, n in counts.most_common(args.top):
        print(f"  {n:6d}  {key}")
    if args.no_xla:
        return 0
    ph = xla_phases(lowered, compiler_options())
    hlo = sum(v for k, v in ph.items() if k.startswith("HLO passes"))
    passes = {k: v for k, v in ph.items() if k.islower() and ("-" in k or k.endswith("simp"))}
    print(f"XLA compile {ph['(wall)']:.2f} s: HLO passes {hlo:.2f} s, "
          f"fused kernels {ph.get('FusionCompiler::Compile', 0.0):.2f} s, "
          f"LLVM {ph.get('JitCompiler::Compile', 0.0):.2f} s")  # fmt: skip
    slowest = sorted(passes.items(), key=lambda kv: -kv[1])[: args.top]
    print("slowest HLO passes: " + ", ".join(f"{k} {v:.2f} s" for k, v in slowest))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
