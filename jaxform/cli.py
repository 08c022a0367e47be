"""jaxform: differentiable finite-element simulation of metal forming (mm, MPa, s, N, K).

jaxform run CONFIG [--set section.key=value ...] --out DIR
jaxform material-point [--material NAME] [--rates R ...] [--strain E] --out DIR
jaxform taylor-test CONFIG [--set section.key=value ...] [--groups G ...]
jaxform design CONFIG [--set section.key=value ...] --out DIR
jaxform study CONFIG [--set section.key=value ...] --out DIR [--cluster ADDRESS] [--resume]
"""
# The command line: the only module that prints.

from __future__ import annotations

import argparse
import atexit
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

# material-point limits: a step count whose history fits memory, rates and speeds of forging
MAX_MATERIAL_POINT_STEPS = 1_000_000
MAX_RATE_1_S = 1e6


class UsageError(ValueError):
    """A bad flag: the message names it and what is allowed (exit status 2)."""


class _Parser(argparse.ArgumentParser):
    """argparse, reporting a bad command line in one line (not the usage block)."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


class Progress:
    """The run's progress: a tqdm bar redrawn in place on a terminal, one line per compiled
    chunk otherwise (a log file or a pipe gets no carriage returns)."""

    def __init__(self, stream):
        self.stream, self.bar, self.first_s = stream, None, None
        self.t0 = time.perf_counter()
        self.tty = bool(getattr(stream, "isatty", lambda: False)())

    @staticmethod
    def describe(p: dict) -> str:
        new_mesh = ""
        if p.get("remeshed"):
            new_mesh = f" remeshed ({p.get('remesh_trigger', '')}): {p['remeshed']} nodes"
        return (
            f"t={p['time_s']:.3f} s dt={p['dt_s']:.4g} s stroke={p['stroke_mm']:.4f} mm "
            f"force={p['force_N']:.3f} N newton={int(p['iterations'])} "
            f"cutbacks={int(p['cutbacks'])}{new_mesh}"
        )

    def __call__(self, p: dict) -> None:
        if self.first_s is None:
            self.first_s = time.perf_counter() - self.t0
        if self.tty:
            from tqdm import tqdm

            if self.bar is None:
                self.bar = tqdm(total=p["n_steps"], file=self.stream, unit="step")
            self.bar.total = p["n_steps"]
            self.bar.set_postfix_str(self.describe(p), refresh=False)
            self.bar.update(p["step"] - self.bar.n)
        elif p["chunk_end"] or p.get("remeshed"):
            print(f"step {p['step']}/{p['n_steps']}: {self.describe(p)}", file=self.stream,
                  flush=True)  # fmt: skip

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


class ForwardProgress:
    """The progress of a gradient command's forward run: a line per compiled chunk, and
    when it ends, that the gradient program is compiled next (minutes on a large scene)."""

    def __init__(self, t0: float):
        self.t0 = t0

    def __call__(self, p: dict) -> None:
        if not (p["chunk_end"] or p.get("remeshed")):
            return
        took = f"({time.perf_counter() - self.t0:.1f} s)"
        print(f"  forward step {p['step']}/{p['n_steps']}: {Progress.describe(p)} {took}",
              flush=True)  # fmt: skip
        if p["chunk_end"] and p["step"] >= p["n_steps"]:
            print("  forward run done; compiling the gradient program and evaluating the "
                  "start design", flush=True)  # fmt: skip


def check_out_dir(out: str) -> None:
    """``--out`` is, or can be made, a writable folder (checked before any computation)."""
    p = Path(out)
    if p.exists() and not p.is_dir():
        raise UsageError(f"--out {out}: is an existing file, not a folder")
    parent = next((a for a in (p, *p.parents) if a.exists()), Path("."))
    if not parent.is_dir():
        raise UsageError(f"--out {out}: {parent} is a file, not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise UsageError(f"--out {out}: {parent} is not writable")


def _check_positive(flag: str, values, high: float) -> None:
    """Every value finite and in (0, high]."""
    bad = [v for v in values if not (math.isfinite(v) and 0.0 < v <= high)]
    if bad:
        raise UsageError(f"{flag} = {bad[0]!r}: every value must lie in (0, {high:g}]")


def _check_material_point_flags(args) -> None:
    if not (math.isfinite(args.strain) and 0.0 < args.strain <= 3.0):
        raise UsageError(f"--strain = {args.strain!r}: must lie in (0, 3]")
    if not 1 <= args.steps <= MAX_MATERIAL_POINT_STEPS:
        raise UsageError(f"--steps = {args.steps}: must lie in [1, {MAX_MATERIAL_POINT_STEPS}]")
    from jaxform.config import MAX_LENGTH_MM

    if args.ram_speeds_mm_s is not None:
        _check_positive("--ram-speeds-mm-s", args.ram_speeds_mm_s, MAX_LENGTH_MM)
        _check_positive("--height-mm", [args.height_mm], MAX_LENGTH_MM)
    else:
        _check_positive("--rates", args.rates, MAX_RATE_1_S)
    check_out_dir(args.out)


def _check_taylor_steps(h) -> None:
    """--h: at least two finite step sizes > 0, strictly decreasing (the rates compare
    neighbours)."""
    ok = (
        len(h) >= 2
        and all(math.isfinite(v) and v > 0 for v in h)
        and all(b < a for a, b in zip(h, h[1:]))
    )
    if not ok:
        raise UsageError(
            f"--h {' '.join(f'{v:g}' for v in h)}: give at least 2 finite step "
            f"sizes > 0, strictly decreasing (e.g. --h 1 0.5 0.25 0.125)"
        )


def _load_checked(args, gradient: bool = False):
    """What a scene command runs, validated once (the driver takes it as it is), or
    ConfigError: everything that can be checked before a scene is built (for gradient
    commands also the design set-up).  A command of one scene gets its
    :class:`jaxform.config.Config`; ``jaxform run`` of a config with
    ``[[process.operation]]`` tables its :class:`jaxform.process_config.Process`.  The
    sections that the scene takes from the defaults and a user would expect to write
    ([material]; for ``design`` [design]) are named on stdout."""
    from jaxform.config import (
        check_design_run,
        check_gradient_run,
        defaulted_sections,
        given_sections,
        load_config,
        read_document,
        typed,
    )
    from jaxform.process_config import Process, check_process_design, load_typed

    raw = read_document(args.config)  # read once: loaded below, its sections named after
    # a gradient command of one scene reads the scene's config; a process
    # ([[process.operation]]) its operations and [design] (jaxform.process_design)
    process = "process" in raw
    loaded = (
        typed(load_config(raw, args.set)) if gradient and not process else load_typed(raw, args.set)
    )
    if gradient and process:
        taylor = args.command != "design" and args.groups
        check_process_design(loaded, args.groups if taylor else None,
                             "--groups" if taylor else "design.variables")  # fmt: skip
    elif gradient and args.command == "design":
        check_design_run(loaded)
    elif gradient:
        check_gradient_run(loaded, args.groups, "--groups")
    # a process: the base sections as its first operation's scene has them
    cfg = loaded.operations[0].config if isinstance(loaded, Process) else loaded
    for line in defaulted_sections(cfg, given_sections(raw, args.set), args.command):
        print(line, flush=True)
    return loaded


def _material_point(args) -> int:
    import jax
    import jax.numpy as jnp

    from jaxform.io import write_csv
    from jaxform.materialpoint import Ram, uniaxial_compression
    from jaxform.materials import load_material
    from jaxform.plot import stress_strain
    from jaxform.xla_options import jit

    law, params = load_material(args.material, key="--material")  # ConfigError: exit 2
    _check_material_point_flags(args)
    by_speed = args.ram_speeds_mm_s is not None
    loads = args.ram_speeds_mm_s if by_speed else args.rates
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)

    def one(load):
        kw = dict(ram=Ram(load, args.height_mm)) if by_speed else dict(strain_rate_1_s=load)
        return uniaxial_compression(law, params, final_strain=args.strain, n_steps=args.steps, **kw)

    t0 = time.perf_counter()
    res = jit(jax.vmap(one))(jnp.asarray(loads, dtype=jnp.float64))
    res = {k: np.asarray(v) for k, v in res.items()}
    print(
        f"material point: {len(loads)} loadings x {args.steps} steps in "
        f"{time.perf_counter() - t0:.2f} s (including compilation)"
    )
    curves = {}
    unit = "mm/s" if by_speed else "/s"
    for i, rate in enumerate(loads):
        if not res["ok"][i].all():
            bad = int(np.argmin(res["ok"][i]))
            print(f"{rate:g} {unit}: local solve failed at step {bad}", file=sys.stderr)
            return 2
        name = (
            f"uniaxial_speed_{rate:g}_mm_s.csv" if by_speed else f"uniaxial_rate_{rate:g}_1_s.csv"
        )
        write_csv(
            out_dir / name,
            {
                "time_s": res["time_s"][i],
                "strain": res["strain"][i],
                "stress_MPa": res["stress_MPa"][i],
                "s_MPa": res["s_MPa"][i],
                "eqps": res["eqps"][i],
            },
        )
        curves[f"{rate:g} {unit}"] = (res["strain"][i], res["stress_MPa"][i])
        print(
            f"  {rate:>8g} {unit}: stress at strain {args.strain:g} = "
            f"{res['stress_MPa'][i][-1]:.3f} MPa, s = {res['s_MPa'][i][-1]:.3f} MPa -> {name}"
        )
    png = out_dir / "stress_strain.png"
    stress_strain(curves, png, f"{args.material}: uniaxial compression")
    print(f"wrote {png}")
    return 0


def fold_lines(result) -> list[str]:
    """One line per persisting lap (a wedge: the material folded onto itself) and per
    persisting pocket (air between the material and a die) of a run (:mod:`jaxform.laps`),
    in a process each headed by its operation (to whose end it persists)."""

    def head(fold) -> str:
        return f"{fold['operation']}: " if "operation" in fold else ""

    out = [
        f"{head(lap)}lap: from stroke {lap['stroke_mm']:.4g} mm the free surface folds onto "
        f"itself at ({lap['end_r_mm']:.4g}, {lap['end_z_mm']:.4g}) mm and stays folded to the end, "
        f"fold angle {lap['angle_deg']:.3g} -> {lap['end_angle_deg']:.3g} deg, depth "
        f"{lap['depth_mm']:.3g} mm (history wedge_angle_deg, wedge_depth_mm; "
        f"output.lap_angle_deg)"
        for lap in result.laps
    ]
    out += [
        f"{head(p)}pocket (underfill along the die): from stroke {p['stroke_mm']:.4g} mm air "
        "stays "
        f"between the material and the die at ({p['end_r_mm']:.4g}, {p['end_z_mm']:.4g}) mm, "
        f"closed at both ends by material on the die: gap {1e3 * p['gap_mm']:.3g} um, "
        f"{p['length_mm']:.3g} mm long; not a lap (history pocket_gap_mm, pocket_length_mm)"
        for p in getattr(result, "pockets", [])
    ]
    return out


def _run(args) -> int:
    from jaxform.config import ConfigError
    from jaxform.driver import run
    from jaxform.simulation import SimulationError

    check_out_dir(args.out)
    cfg = _load_checked(args)
    t0 = time.perf_counter()
    progress = Progress(sys.stdout)
    try:
        result = run(cfg, (), out_dir=args.out, progress=progress, lean=True)
    except ConfigError as err:
        progress.close()
        print(f"config error: {err}", file=sys.stderr)
        return 2
    except SimulationError as err:
        progress.close()
        print(f"simulation stopped: {err}", file=sys.stderr)
        print(f"last converged state written to {args.out}", file=sys.stderr)
        return 1
    progress.close()
    first = progress.first_s
    h = result.history
    print(
        f"done: {len(h['time_s']) - 1} steps, {int(h['newton_iterations'].sum())} Newton "
        f"iterations, {int(h['cutbacks'].sum())} cutbacks, {int(h['rezoned'].sum())} rezonings, "
        f"{len(result.remeshes)} remeshes, "
        f"final force {h['force_N'][-1]:.2f} N, "
        f"{time.perf_counter() - t0:.1f} s wall (first chunk incl. compile "
        f"{first or 0:.1f} s)"
    )
    for line in fold_lines(result):
        print(line)
    from jaxform.remesh import mesher_note

    note = mesher_note(result.remeshes)
    if note:
        print(note)
    overlap = float(np.max(h["die_overlap_mm"])) if "die_overlap_mm" in h else 0.0
    if overlap > 1e-3:
        print(
            f"note: a convex die corner reached up to {overlap:.3g} mm into the material "
            f"between contact nodes (history die_overlap_mm); die.corner_contact = true "
            f"holds the facets off it"
        )
    if hasattr(result, "runs"):  # a process: one line per operation
        from jaxform.process_outputs import summary

        print("operations:\n" + "\n".join(summary(result)))
    written = sorted(p.name for p in Path(args.out).iterdir() if p.is_file())
    print(f"outputs in {args.out}: {', '.join(written)}")
    return 0


def _taylor(args) -> int:
    from jaxform.design.taylor import format_table
    from jaxform.driver import run_taylor

    _check_taylor_steps(args.h)
    cfg = _load_checked(args, gradient=True)
    t0 = time.perf_counter()
    print("taylor-test: the forward run of the initial design (it fixes the step schedule)",
          flush=True)  # fmt: skip

    def announce(line):
        print(line, flush=True)

    def evaluated(group, h, j):
        print(f"  {group}: h = {h:g}, J = {j:.10g} ({time.perf_counter() - t0:.1f} s)", flush=True)

    rows, code = _guarded(
        "taylor-test",
        lambda: run_taylor(
            cfg,
            (),
            groups=args.groups,
            h=args.h,
            progress=evaluated,
            forward_progress=ForwardProgress(t0),
            announce=announce,
        ),  # fmt: skip
    )
    if code:
        return code
    print(format_table(rows))
    min_rate = min(r.min_rate for r in rows)
    print(
        f"({time.perf_counter() - t0:.1f} s; groups: {', '.join(r.group for r in rows)}; "
        f"pass: every rate >= 1.9)"
    )
    print(f"min_rate={min_rate:.4f}")
    return 0 if min_rate >= 1.9 else 1


def _guarded(command: str, fn):
    """(fn(), 0), or (None, exit status) with the reason printed: 2 for a config error,
    1 for a run that failed."""
    from jaxform.config import ConfigError
    from jaxform.gradients import GradientRunError
    from jaxform.simulation import SimulationError

    try:
        return fn(), 0
    except ConfigError as err:
        print(f"config error: {err}", file=sys.stderr)
        return None, 2
    except (SimulationError, GradientRunError) as err:
        print(f"{command}: the run failed: {err}", file=sys.stderr)
        return None, 1


def _design(args) -> int:
    from jaxform.driver import run_design

    check_out_dir(args.out)
    cfg = _load_checked(args, gradient=True)
    t0 = time.perf_counter()

    def announce(line):
        print(line, flush=True)

    # a process's [design] is its first operation's config's (jaxform.process_design)
    design = cfg.operations[0].config.design if hasattr(cfg, "operations") else cfg.design
    sampling = design.optimizer in ("lhs_rsm", "cmaes")

    def progress(it, val, gnorm, design):
        if sampling:  # per run: the runs used, its objective, the best so far
            print(f"simulation {it:4d}: objective {val:.8g}  best {gnorm:.8g}  "
                  f"({time.perf_counter() - t0:.1f} s)", flush=True)  # fmt: skip
            return
        print(
            f"iteration {it:3d}: objective {val:.8g}  |projected grad| {gnorm:.3e}  "
            f"({time.perf_counter() - t0:.1f} s)",
            flush=True,
        )

    print("design: the forward run of the initial design (it fixes the step schedule)",
          flush=True)  # fmt: skip
    out, code = _guarded(
        "design",
        lambda: run_design(
            cfg,
            (),
            out_dir=args.out,
            progress=progress,
            forward_progress=ForwardProgress(t0),
            announce=announce,
        ),  # fmt: skip
    )
    if code:
        return code
    problem, hist = out
    final = problem.physical(hist.designs[hist.best])
    steps = "runs" if sampling else "iterations"
    print(
        f"done ({hist.stop_reason}): objective {hist.objective[0]:.6g} -> "
        f"{hist.objective[hist.best]:.6g} in {len(hist.objective) - 1} {steps}, "
        f"{hist.evaluations} simulations, {hist.rejected} rejected trials, "
        f"{time.perf_counter() - t0:.1f} s"
    )
    print("design: " + ", ".join(f"{k} = {v:.6g}" for k, v in final.items()))
    written = sorted(p.name for p in Path(args.out).iterdir() if p.is_file())
    print(f"outputs in {args.out}: {', '.join(written)}")
    return 0


class StudyProgress:
    """A study's progress: samples done of all, failures, time left (tqdm on a terminal, a
    line per sample otherwise)."""

    def __init__(self, stream):
        self.stream, self.bar, self.t0, self.start = stream, None, time.perf_counter(), None
        self.tty = bool(getattr(stream, "isatty", lambda: False)())

    def __call__(self, done: int, total: int, failed: int) -> None:
        if self.tty:
            from tqdm import tqdm

            if self.bar is None:
                self.bar = tqdm(total=total, initial=done, file=self.stream, unit="sample")
            self.bar.set_postfix_str(f"{failed} failed", refresh=False)
            self.bar.update(done - self.bar.n)
            return
        if self.start is None:  # the samples a resumed study found done
            self.start = done
            return
        ran, elapsed = done - self.start, time.perf_counter() - self.t0
        left = elapsed / ran * (total - done) if ran else float("nan")
        print(f"sample {done}/{total} done, {failed} failed, {elapsed:.0f} s, "
              f"about {left:.0f} s left", file=self.stream, flush=True)  # fmt: skip

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _study(args) -> int:
    from jaxform.study.analysis import sensitivities, write_figures, write_sensitivities
    from jaxform.study.engine import RESULTS, Where, check_cluster_address, read_table, run_study
    from jaxform.study.spec import build_study

    check_out_dir(args.out)
    if not 0 <= args.workers <= 4096:
        raise UsageError(f"--workers = {args.workers}: must lie in [0, 4096] (0: one per core)")
    if args.cluster is not None:
        check_cluster_address(args.cluster)
    study = build_study(args.config, args.set)
    progress = StudyProgress(sys.stdout)
    where = Where(cluster=args.cluster, workers=args.workers)
    try:
        summary = run_study(study, args.config, args.set, args.out, where, args.resume, progress)
    except KeyboardInterrupt:
        progress.close()
        print(f"study interrupted: the finished samples are in {args.out}/{RESULTS}; "
              f"--resume runs the rest", file=sys.stderr)  # fmt: skip
        return 130
    progress.close()
    records = sensitivities(study, read_table(Path(args.out) / RESULTS))
    write_sensitivities(records, Path(args.out) / "sensitivity.csv")
    figures = write_figures(study, args.out, records)
    print(
        f"done: {summary.ran} samples run ({summary.failed} failed), {summary.skipped} found "
        f"done, {summary.total} in the plan, {summary.wall_s:.1f} s on "
        f"{len(summary.workers) or 'no'} workers"
    )
    for resp in study.responses:
        top = sorted((r for r in records if r["response"] == resp.name and r["rank"] > 0),
                     key=lambda r: r["rank"])  # fmt: skip
        if top:
            print(f"{resp.name}: inputs by sensitivity: "
                  + ", ".join(f"{r['input']}" for r in top))  # fmt: skip
    names = [RESULTS, "plan.csv", "sensitivity.csv", *(p.name for p in figures)]
    print(f"outputs in {args.out}: {', '.join(names)}")
    return 0 if summary.failed == 0 else 1


def _cache_setting(args) -> str:
    """``[solver] compilation_cache_dir`` of a study's config ('auto' without one, or when
    the config is invalid: the command itself then reports why)."""
    from jaxform.config import ConfigError, load_config, typed

    if getattr(args, "config", None) is None:
        return "auto"
    try:
        doc = load_config(args.config, list(getattr(args, "set", [])))
    except (ConfigError, OSError):
        return "auto"
    return typed(doc).solver.compilation_cache_dir


def _scene_arguments(parser, config_help: str) -> None:
    """The arguments of every scene command: the config and its --set overrides."""
    parser.add_argument("config", help=config_help)
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="SECTION.KEY=VALUE",
        help="override a config value (repeatable)",
    )


def main(argv: list[str] | None = None) -> int:
    from jaxform.host_memory import map_large_blocks
    from jaxform.precision import enable_x64

    enable_x64()
    map_large_blocks()  # freed chunks' blocks go back to the system (jaxform.host_memory)
    parser = _Parser(
        prog="jaxform", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = parser.add_subparsers(dest="command", required=True)

    rp = sub.add_parser("run", help="run a forging scene from a TOML config")
    _scene_arguments(rp, "scene config (TOML), e.g. configs/upsetting_seed.toml")
    rp.add_argument("--out", default="out/run", help="output folder")
    rp.set_defaults(func=_run)

    mp = sub.add_parser("material-point", help="uniaxial compression of one material point")
    mp.add_argument(
        "--material",
        default="al1100_673K",
        help="material preset name (jaxform/materials/data) or a .toml path",
    )
    mp.add_argument(
        "--rates",
        type=float,
        nargs="+",
        default=[0.001, 0.01, 0.1, 1.0],
        help="true strain rates in 1/s",
    )
    mp.add_argument(
        "--ram-speeds-mm-s",
        type=float,
        nargs="+",
        default=None,
        help="constant ram speeds in mm/s instead of true strain rates",
    )
    mp.add_argument(
        "--height-mm",
        type=float,
        default=7.5,
        help="specimen height in mm (with --ram-speeds-mm-s)",
    )
    mp.add_argument("--strain", type=float, default=1.0, help="final true strain")
    mp.add_argument("--steps", type=int, default=1000, help="number of equal steps")
    mp.add_argument("--out", default="out/material_point", help="output folder")
    mp.set_defaults(func=_material_point)

    tp = sub.add_parser("taylor-test", help="check the scene's gradients (Taylor remainders)")
    _scene_arguments(tp, "scene config (TOML)")
    tp.add_argument(
        "--groups",
        nargs="+",
        default=None,
        help="design groups to test (default: every group of the scene)",
    )
    tp.add_argument(
        "--h",
        type=float,
        nargs="+",
        default=[1.0, 0.5, 0.25, 0.125],
        help="decreasing step sizes (multiples of the random direction)",
    )
    tp.set_defaults(func=_taylor)

    dp = sub.add_parser("design", help="gradient-based design from the config's [design]")
    _scene_arguments(dp, "scene config (TOML) with a [design] section")
    dp.add_argument("--out", default="out/design", help="output folder")
    dp.set_defaults(func=_design)

    st = sub.add_parser("study", help="design of experiments / robustness study from [study]")
    _scene_arguments(st, "scene config (TOML) with a [study] section")
    st.add_argument("--out", default="out/study", help="output folder (results.csv, plots)")
    st.add_argument(
        "--cluster", default=None, metavar="ADDRESS",
        help="a Dask scheduler (tcp://HOST:PORT); default: worker processes on this machine",
    )  # fmt: skip
    st.add_argument("--workers", type=int, default=0,
                    help="local worker processes (0: one per core)")  # fmt: skip
    st.add_argument("--resume", action="store_true",
                    help="run only the samples the table in --out lacks")  # fmt: skip
    st.set_defaults(func=_study)

    args = parser.parse_args(argv)
    if args.func in (_material_point, _study):  # warm start: see jaxform/cache.py; run,
        # design and taylor-test enable it where they run (jaxform.driver)
        from jaxform.cache import enable_compilation_cache

        enable_compilation_cache(_cache_setting(args))
    return _refusing(args)


def _refusing(args) -> int:
    """Run the command; a bad flag or config found before the run: one line, exit 2."""
    from jaxform.config import ConfigError

    try:
        return args.func(args)
    except UsageError as err:
        print(f"jaxform {args.command}: error: {err}", file=sys.stderr)
    except ConfigError as err:
        print(f"config error: {err}", file=sys.stderr)
    return 2


def entry() -> None:
    """The ``jaxform`` console script: :func:`main`, then a quick exit.

    By the time :func:`main` returns, the command's files are written and closed.  Tearing
    down the interpreter with XLA's runtime and the compiled programs loaded in it would
    still take 0.3-0.6 s, a fifth of a warm seed run (docs/benchmarks.md, "Time to first
    result"), so the exit handlers run (``atexit``: logging, JAX's own), the streams are
    flushed and the process ends at once with the command's status.  A reader of stdout
    that went away (``jaxform ... | head``) ends the command with status 1 and no
    traceback; any other exception, and ``--help``, leave the usual way."""
    try:
        code = main()
    except BrokenPipeError:  # the reader of stdout went away (jaxform ... | head)
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        code = 1
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe (jaxform ... | head): nothing to keep
            pass
    os._exit(int(code or 0))  # as sys.exit: None is success


if __name__ == "__main__":
    entry()
