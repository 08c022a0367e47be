"""Cost of a Newton iteration against the number of unknowns, and the 100x100 seed scene.

    python experiments/bench_scale.py [--meshes 10 20 40 80 160] [--quick] [--out docs/figures]
    python experiments/bench_scale.py --full 100 [--newton auto|newton|modified]
                                                        # the seed scene to 56.3 %, timed
    python experiments/bench_scale.py --full 100 --anderson 0 3 [--config C] [--set k=v ...]
                                  # modified Newton with and without Anderson, interleaved

Seed scene (configs/upsetting_seed.toml, q1q1, Anand) on n x n meshes, klujax sparse LU.
Each size runs in its own subprocess (``--one n``, so that its peak resident memory,
``ru_maxrss``, is that size's alone) and times the compiled pieces of a Newton iteration
separately, in turn, best of 5 rounds after compilation (``timing.interleaved``: a shared
machine's drifting speed slows every piece alike, so the ratios hold):

* ``assemble``: ``Model.residual_and_jacobian`` (the residual pass with the nested Anand
  local solves over the whole mesh, the jacfwd Jacobian pass at its solution in chunks of
  ``Model.jacobian_chunk`` elements, contact blocks, the segment_sum onto the pattern);
* ``residual``: ``Model.residual`` (one per line-search trial, i.e. one per iteration);
* ``solve``: ``LinearSolver.solve`` on the fixed pattern (klujax: numeric factorization
  and solve in one call, with the pattern's symbolic analysis done once at set-up);
* ``factor``: ``LinearSolver.refactor`` alone (the numeric factorization modified Newton
  keeps) and ``kept solve``: ``LinearSolver.solve_factored`` with it (the triangular
  solves of an iteration that reuses it),

evaluated at the first step's homogeneous compression (u_r = e r / 2, u_z = -e z, the
flow the scene starts with).  One Newton iteration = assemble + solve + residual; one
modified-Newton iteration with a kept factorization = residual + kept solve.
Writes bench_scale.csv and bench_scale.png (log-log, with power-law exponents fitted over
the sizes >= 20x20).
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from functools import partial
from pathlib import Path

import numpy as np
from timing import interleaved

SEED = "configs/upsetting_seed.toml"


def one(n: int, linear: str) -> dict:
    """Time the compiled pieces on an n x n seed mesh (run in a fresh process)."""
    import jax
    import jax.numpy as jnp

    import jaxform
    from jaxform.config import load_config
    from jaxform.scenes import build_scene
    from jaxform.stepping import initial_state, step_context
    from jaxform.xla_options import jit

    jaxform.enable_x64()
    cfg = load_config(
        SEED,
        [
            f"mesh.nr={n}",
            f"mesh.nz={n}",
            f"solver.linear={linear}",
            "output.fields=false",
            "output.plots=false",
        ],
    )
    sc = build_scene(cfg)
    lay, idx, inp, model = sc.model.layout, sc.idx, sc.inputs, sc.model
    st = initial_state(sc.model, sc.inputs)
    coords = np.asarray(inp.coords)
    e = cfg["die"]["speed_mm_s"] * sc.dt / cfg["billet"]["height_mm"]  # first step's strain
    x = np.zeros(lay.n_dofs)
    u = x[: lay.n_node_dofs].reshape(-1, lay.n_fields)
    u[:, 0], u[:, 1] = 0.5 * e * coords[:, 0], -e * coords[:, 1]
    x = jnp.asarray(x)
    t, dt = jnp.asarray(sc.dt), jnp.asarray(sc.dt)
    ctx = step_context(model, st, inp, idx, t, dt)
    # compiled as the simulation compiles its programs (jaxform.xla_options)
    rj = jit(model.residual_and_jacobian)
    res = jit(model.residual)
    sym = idx.lu_symbolic
    solve = jax.jit(lambda r, c, v, b: sc.linear.solve(r, c, v, b, lay.n_dofs, sym))
    none = sc.linear.empty_factorization(lay.n_dofs, x.dtype)
    factor = jax.jit(lambda v: sc.linear.refactor(idx.rows, idx.cols, v, lay.n_dofs, sym, none))
    kept_solve = jax.jit(lambda f, b: sc.linear.solve_factored(f, b, sym))
    out = {"n": n, "unknowns": lay.n_dofs, "nonzeros": lay.n_nonzeros, "backend": sc.linear.backend}
    t0 = time.perf_counter()
    r, vals, *_ = jax.block_until_ready(rj(x, ctx))
    out["compile_assemble_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    jax.block_until_ready(res(x, ctx))
    out["compile_residual_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    dx = jax.block_until_ready(solve(idx.rows, idx.cols, vals, -r))
    out["compile_solve_s"] = time.perf_counter() - t0
    fac = jax.block_until_ready(factor(vals))
    # all pieces timed in turn, best of 5 rounds: their ratios survive a drifting machine
    names = ("assemble_s", "residual_s", "solve_s", "factor_s", "kept_solve_s")
    times = interleaved(
        [
            lambda: rj(x, ctx),
            lambda: res(x, ctx),
            lambda: solve(idx.rows, idx.cols, vals, -r),
            lambda: factor(vals),
            lambda: kept_solve(fac, -r),
        ],
        5,
        release={3: sc.linear.release},
    )
    out.update(zip(names, times))
    jax.block_until_ready(sc.linear.release(fac))
    out["iteration_s"] = out["assemble_s"] + out["solve_s"] + out["residual_s"]
    out["kept_iteration_s"] = out["residual_s"] + out["kept_solve_s"]
    out["solve_finite"] = bool(np.all(np.isfinite(np.asarray(dx))))
    out["peak_rss_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return out


def full(n: int, newton: str, config: str, depths: list[int], sets: list[str]) -> None:
    """A scene (default the seed, to 56.3 %) on n x n, once per ``solver.anderson_depth`` in
    ``depths``: a first run each (compile + run), then two rounds of runs interleaved
    (the drift of a shared host slows each alike), the best of each printed."""
    import jaxform
    from jaxform.config import load_config
    from jaxform.scenes import build_scene
    from jaxform.simulation import simulate

    jaxform.enable_x64()
    scenes = {}
    for d in depths:
        cfg = load_config(
            config,
            [
                f"mesh.nr={n}",
                f"mesh.nz={n}",
                "output.fields=false",
                "output.plots=false",
                f"solver.newton={newton}",
                f"solver.anderson_depth={d}",
                *sets,
            ],
        )
        t0 = time.perf_counter()
        scenes[d] = build_scene(cfg)
        simulate(scenes[d])
        print(f"anderson_depth={d}: first run {time.perf_counter() - t0:.1f} s", flush=True)
    results = {}

    def run(d):
        results[d] = simulate(scenes[d])

    best = dict(zip(depths, interleaved([partial(run, d) for d in depths], 2, warm_up=False)))
    for d in depths:
        h, scene = results[d].history, scenes[d]
        its = h["newton_iterations"][1:]
        print(
            f"{config} {n}x{n}: {scene.model.layout.n_dofs} unknowns, {len(its)} steps, "
            f"{type(scene.newton.variant).__name__}, anderson_depth {d}, "
            f"{h['factorizations'][1:].sum():.0f} factorizations, "
            f"{its.sum():.0f} iterations ({its.mean():.2f}/step), "
            f"{h['cutbacks'][1:].sum():.0f} cutbacks, {h['remeshed'][1:].sum():.0f} remeshes: "
            f"run after compile {best[d]:.1f} s (best of 2, interleaved; "
            f"{best[d] / its.sum() * 1e3:.0f} ms per iteration incl. step overhead), "
            f"force {h['force_N'][-1]:.2f} N, peak RSS "
            f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB",
            flush=True,
        )


def fit(unknowns, seconds):
    k, c = np.polyfit(np.log(unknowns), np.log(seconds), 1)
    return float(k), float(np.exp(c))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--meshes", type=int, nargs="+", default=[10, 20, 40, 80, 160])
    ap.add_argument("--quick", action="store_true", help="10, 20, 40 only")
    ap.add_argument("--linear", default="sparse")
    ap.add_argument("--out", default="docs/figures")
    ap.add_argument("--one", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--full", type=int, help="time the whole seed scene on this n x n mesh")
    ap.add_argument(
        "--newton",
        default="auto",
        choices=("auto", "newton", "modified"),
        help="solver.newton of the --full run",
    )
    ap.add_argument("--config", default=SEED, help="the scene of the --full run")
    ap.add_argument(
        "--anderson",
        type=int,
        nargs="+",
        default=[3],
        help="solver.anderson_depth values of the --full run, compared in one process",
    )
    ap.add_argument("--set", nargs="*", default=[], help="more overrides of the --full run")
    args = ap.parse_args()
    if args.one:
        print("RESULT " + json.dumps(one(args.one, args.linear)), flush=True)
        return
    if args.full:
        return full(args.full, args.newton, args.config, args.anderson, args.set)
    meshes = [10, 20, 40] if args.quick else args.meshes
    rows = []
    print(
        f"{'mesh':>9} {'unknowns':>8} {'nonzeros':>9} {'assemble':>9} {'residual':>9} "
        f"{'solve':>8} {'iteration':>9} {'factor':>8} {'kept':>7} {'peak RSS':>9} "
        f"{'compile a/r/s':>15}"
    )
    for n in meshes:
        p = subprocess.run(
            [sys.executable, __file__, "--one", str(n), "--linear", args.linear],
            capture_output=True,
            text=True,
        )
        line = [ln for ln in p.stdout.splitlines() if ln.startswith("RESULT ")]
        if p.returncode or not line:
            print(f"{n}x{n}: failed\n{p.stderr[-2000:]}")
            break
        r = json.loads(line[0][7:])
        rows.append(r)
        print(
            f"{n:>4}x{n:<4} {r['unknowns']:>8} {r['nonzeros']:>9} "
            f"{r['assemble_s'] * 1e3:>7.1f}ms "
            f"{r['residual_s'] * 1e3:>7.1f}ms {r['solve_s'] * 1e3:>6.1f}ms "
            f"{r['iteration_s'] * 1e3:>7.1f}ms {r['factor_s'] * 1e3:>6.1f}ms "
            f"{r['kept_solve_s'] * 1e3:>5.1f}ms {r['peak_rss_mib']:>6.0f}MiB "
            f"{r['compile_assemble_s']:>5.1f}/{r['compile_residual_s']:.1f}/"
            f"{r['compile_solve_s']:.1f}s",
            flush=True,
        )
    if len(rows) < 2:
        return
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    keys = (
        "n",
        "unknowns",
        "nonzeros",
        "assemble_s",
        "residual_s",
        "solve_s",
        "iteration_s",
        "factor_s",
        "kept_solve_s",
        "kept_iteration_s",
        "peak_rss_mib",
        "compile_assemble_s",
        "compile_residual_s",
        "compile_solve_s",
    )
    from jaxform.io import write_csv

    write_csv(out / "bench_scale.csv", {k: np.array([float(r[k]) for r in rows]) for k in keys})
    nu = np.array([r["unknowns"] for r in rows], dtype=float)
    sel = (
        np.array([r["n"] >= 20 for r in rows])
        if sum(r["n"] >= 20 for r in rows) >= 2
        else np.ones(len(rows), bool)
    )
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    for key, label, mk in (
        ("assemble_s", "assembly (R and Jacobian)", "o"),
        ("residual_s", "residual", "^"),
        ("solve_s", "sparse LU (klujax): factor + solve", "s"),
        ("iteration_s", "Newton iteration", "D"),
        ("kept_iteration_s", "iteration with a kept LU", "v"),
    ):
        y = np.array([r[key] for r in rows])
        k, c = fit(nu[sel], y[sel])
        print(f"{label:>26}: time ~ unknowns^{k:.2f}")
        ax.loglog(nu, y, mk + "-", label=f"{label}: exponent {k:.2f}")
    ax.set_xlabel("unknowns")
    ax.set_ylabel("time per call (s)")
    ax.set_title("seed scene, q1q1 Anand, 2-core CPU")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "bench_scale.png", dpi=120)
    mem = np.array([r["peak_rss_mib"] for r in rows])
    k, _ = fit(nu[sel], mem[sel])
    print(f"{'peak RSS':>26}: MiB ~ unknowns^{k:.2f}")
    print(f"wrote {out / 'bench_scale.csv'} and {out / 'bench_scale.png'}")


if __name__ == "__main__":
    main()
