"""Config in, files out: what `jaxform run`, `jaxform design` and `jaxform taylor-test` do.

:func:`run`, one call from a config to a history, fields and output files:

config (TOML path or dict) --load_typed--> Config (or a Process of several operations)
  --build_scene--> Scene --simulate--> Result
  --write_outputs--> history.csv, config.toml, fields.pvd + VTUs, PNGs (with [wear]:
  wear_<die>.csv, wear.png; with output.flow_line_spacing_mm: flow_lines.png/.pvd)
"""

from __future__ import annotations

import csv
from collections.abc import Callable
from pathlib import Path

import numpy as np

from jaxform.cache import enable_compilation_cache
from jaxform.config import Config, dump_config, load_config, typed
from jaxform.damage import CRITERIA
from jaxform.flowlines import flow_lines
from jaxform.forming_outputs import damage_flags, wear_profiles
from jaxform.io import VtuSeries, write_csv, write_flow_lines, write_vtu_series, write_wear
from jaxform.postprocess import die_outlines, nodal_temperature, positions
from jaxform.precision import require_x64
from jaxform.process_config import Process, load_typed
from jaxform.scenes import build_scene
from jaxform.simulation import (
    FIELD_KEYS,
    HISTORY_KEYS,
    Result,
    SimulationError,
    die_force_column,
    simulate,
)


def run(
    config,
    overrides=(),
    out_dir: str | Path | None = None,
    progress: Callable[[dict], None] | None = None,
    lean: bool = False,
) -> Result:
    """Validate, build and run a scene; write outputs to out_dir if given.

    Arguments:
        config: the path of a TOML scene or a nested dict (:func:`jaxform.config.load_config`),
            or what :func:`jaxform.process_config.load_typed` made of one (a
            :class:`jaxform.config.Config` or a :class:`jaxform.process_config.Process`:
            not validated again; no overrides then).
        overrides: ``section.key=value`` strings applied to it.
        out_dir: folder for history.csv, config.toml, fields and plots (None: none written).
        progress: called after each compiled chunk with a dict (step, n_steps, time_s,
            stroke_mm, force_N, iterations, cutbacks).
        lean: the result holds for every row only the fields the outputs read
            (:func:`fields_written`; the others for the last row), and the ParaView
            series is written row by row as the run goes (:class:`jaxform.io.VtuSeries`),
            as ``jaxform run`` asks: a large mesh's stresses and damage are not held for
            every step (a process of several operations keeps every field and writes its
            series at the end).  False: every field of every row.

    Returns:
        the :class:`jaxform.simulation.Result` (history and fields).

    Raises:
        ConfigError: a bad config.  SimulationError (with ``.result``): a step failed
        after all cutbacks; the outputs of the last converged state are written.
    """
    loaded = _loaded(config, overrides, load_typed)
    if isinstance(loaded, Process):  # several operations (jaxform.process)
        return _run_process(loaded, out_dir, progress)
    enable_compilation_cache(loaded.solver.compilation_cache_dir)
    scene = build_scene(loaded)
    series = VtuSeries(out_dir) if lean and out_dir is not None and loaded.output.fields else None
    keep = fields_written(loaded, series is not None) if lean else FIELD_KEYS
    try:
        result = simulate(scene, progress, keep_fields=keep, on_row=series)
    except SimulationError as err:
        if out_dir is not None:
            write_outputs(out_dir, err.result, series)
        raise
    if out_dir is not None:
        write_outputs(out_dir, result, series)
    return result


def fields_written(cfg: Config, streamed: bool = False) -> tuple[str, ...]:
    """The output fields :func:`write_outputs` reads at rows before the last: every one
    for the ParaView series (unless ``streamed``: written as the rows came); else the
    unknowns (history columns, flow lines), the contact fields of the contact-profile
    plot and the strain of the animation's frames."""
    out = cfg.output
    if out.fields and not streamed:
        return FIELD_KEYS
    keep = {"x"}
    if out.plots:
        keep |= {"slip_mm", "contact_status"} | ({"eqps"} if out.animation else set())
    return tuple(k for k in FIELD_KEYS if k in keep)


def _loaded(config, overrides, load: Callable):
    """``config`` itself where it is loaded already (a Config or a Process, no overrides),
    else ``load(config, overrides)``."""
    if isinstance(config, Config | Process):
        if tuple(overrides):
            raise ValueError("overrides apply to a config path or dict, not to a loaded config")
        return config
    return load(config, list(overrides))


def _scene_config(config, overrides) -> Config:
    """The typed config of a command of one scene (design, taylor-test): a process is
    refused by :func:`jaxform.config.load_config`."""
    return _loaded(config, overrides, lambda c, o: typed(load_config(c, o)))


def _run_process(process: Process, out_dir, progress):
    """A config with [[process.operation]] tables: its operations checked (nothing
    compiled), run in order, the process's files written (also when one stops)."""
    from jaxform.process import OperationRefused, prepare, run_process
    from jaxform.process_outputs import write_process_outputs

    ops, doc = process.operations, process.document
    initial = prepare(ops)
    enable_compilation_cache(ops[0].config.solver.compilation_cache_dir)
    try:
        result = run_process(ops, initial, progress, simulate_fn=simulate)
    except (SimulationError, OperationRefused) as err:  # what was reached is written
        if out_dir is not None and err.result is not None:
            write_process_outputs(out_dir, err.result, doc)
        raise
    if out_dir is not None:
        write_process_outputs(out_dir, result, doc)
    return result


def write_outputs(out_dir: str | Path, result: Result, series: VtuSeries | None = None) -> None:
    """history.csv, config.toml, the ParaView series (``series``: the one written as the
    run went, closed here; None: written here from ``result.fields``), the plots."""
    from jaxform import plot

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    scene = result.scene
    cfg = scene.settings
    h = result.history
    if scene.workpiece.pressed:
        keys = ("time_s", "dt_s", "stroke_mm", "force_N", "newton_iterations", "cutbacks",
                "friction_work_Nmm")  # fmt: skip
        cols = {k: h[k] for k in keys}
    else:  # no die: the applied load
        cols = {"time_s": h["time_s"], "dt_s": h["dt_s"], "load_N": h["force_N"],
                "newton_iterations": h["newton_iterations"], "cutbacks": h["cutbacks"]}  # fmt: skip
    # the workpiece's and the die's own columns (ring diameters, membrane tip, die fill)
    cols.update({k: v for k, v in h.items() if k not in HISTORY_KEYS and k not in cols})
    if scene.rezone_quality > 0:  # worst element corner quality; 1 where the mesh was rezoned
        cols.update({k: h[k] for k in ("mesh_quality", "rezoned")})
    if scene.remesh is not None:  # 1 on the steps after which the section was remeshed
        cols.update({k: h[k] for k in ("mesh_quality", "remeshed")})
    write_csv(out / "history.csv", cols)
    dump_config(cfg.to_dict(), out / "config.toml")
    if result.failure:
        (out / "FAILED.txt").write_text(result.failure + "\n")
    else:  # a failure an earlier run left in this folder is not this run's
        (out / "FAILED.txt").unlink(missing_ok=True)
    if cfg.output.fields and series is not None:
        series.close(h["time_s"])
    elif cfg.output.fields:
        write_vtu_series(out, result)
    _forming_outputs(out, result)
    if cfg.output.plots:
        final = result.final_scene  # the last mesh (the first one without remeshing)
        coords0 = np.asarray(scene.inputs.coords)
        coords1 = positions(final, result.fields["x"][-1])
        el, el1 = np.asarray(scene.mesh.elements), np.asarray(final.mesh.elements)
        mesh_text = f"{cfg.mesh.element}, {cfg.mesh.nr}x{cfg.mesh.nz}"
        if result.remeshes:
            mesh_text += f", {len(result.remeshes)} remeshes"
        axi = scene.model.formulation.axisymmetric
        axes = ("r [mm]", "z [mm]") if axi else ("x [mm]", "y [mm]")
        if not scene.workpiece.pressed:
            _membrane_plots(out, result, coords0, coords1, el, mesh_text, axes)
            return
        red = 100.0 * h["stroke_mm"][-1] / scene.workpiece.reference_height_mm
        press = scene.press
        die_names = getattr(scene.inputs.die, "names", ())  # several dies: each one's force
        plot.force_stroke(
            h["stroke_mm"],
            h["force_N"],
            out / "force_stroke.png",
            f"{mesh_text}, friction {cfg.friction.model}, {press.name} press",
            per_die={n: h[die_force_column(n)] for n in die_names if die_force_column(n) in h},
            blows=h.get("blow"),
        )
        # the dies where they stand at the last row, in the workpiece's frame
        axes = plot.SectionFrame(axes, die_outlines(scene, float(h["time_s"][-1])))
        plot.deformed_mesh(
            coords0,
            coords1,
            el,
            out / "deformed_mesh.png",
            f"initial and deformed mesh, {red:.1f} % reduction",
            axes,
            elements1=el1,
            marks=plot.Marks(
                laps=tuple((lap["end_r_mm"], lap["end_z_mm"]) for lap in result.laps),
                pockets=tuple((p["end_r_mm"], p["end_z_mm"]) for p in result.pockets),
            ),
        )
        plot.cell_contours(
            coords1,
            el1,
            result.fields["eqps"][-1].mean(axis=1),
            out / "eqps.png",
            f"equivalent plastic strain, {red:.1f} % reduction",
            "equivalent plastic strain [-]",
            axes,
        )
        _contact_plot(out / "contact_profile.png", result)
        _damage_plot(out / "damage.png", result, coords1, el1, red, axes)
        if cfg.output.animation:
            _animation(out / "animation.gif", result, axes.labels)
        temp = nodal_temperature(final, result.fields["x"][-1])
        if temp is not None:
            plot.nodal_contours(
                coords1,
                el1,
                temp,
                out / "temperature.png",
                f"temperature, {red:.1f} % reduction",
                "temperature [K]",
                axes,
            )


def _forming_outputs(out: Path, result: Result) -> None:
    """Die wear profiles (CSV and plot) and flow lines (PNG, ParaView) where asked for."""
    from jaxform import plot

    cfg = result.scene.settings
    wear = wear_profiles(result.final_scene, result.final_state.wear_mm)
    if wear:
        write_wear(out, wear)
        if cfg.output.plots:
            plot.wear_profiles(wear, out / "wear.png")
    spacing = cfg.output.flow_line_spacing_mm
    if spacing > 0.0 and result.scene.workpiece.pressed:
        lines = flow_lines(result, spacing)
        if cfg.output.fields:
            write_flow_lines(out, lines, result.history["time_s"])
        if cfg.output.plots:
            final = result.final_scene
            axi = final.model.formulation.axisymmetric
            labels = ("r [mm]", "z [mm]") if axi else ("x [mm]", "y [mm]")
            t_last = float(result.history["time_s"][-1])
            plot.flow_lines(
                positions(final, result.fields["x"][-1]),
                np.asarray(final.mesh.elements),
                lines.polylines(-1),
                out / "flow_lines.png",
                f"flow lines ({spacing:g} mm apart at the start), stroke "
                f"{result.history['stroke_mm'][-1]:.3g} mm",
                plot.SectionFrame(labels, die_outlines(final, t_last)),
            )


def _damage_plot(path: Path, result: Result, coords1, elements, red: float, axes) -> None:
    """The chosen damage integral (largest Gauss point of each element) on the deformed
    section; with output.damage_critical, the flagged elements outlined in red."""
    from jaxform import plot

    o = result.scene.settings.output
    dmg = np.asarray(result.fields["damage"][-1])[..., CRITERIA.index(o.damage_criterion)]
    fig = plot.cell_contours(
        coords1,
        elements,
        dmg.max(axis=1),
        path,
        f"damage ({o.damage_criterion}), {red:.1f} % reduction",
        f"damage integral {o.damage_criterion} [-]",
        axes,
    )
    flags = damage_flags(result.fields["damage"][-1], o.damage_critical, o.damage_criterion)
    if flags.any():
        ax = fig.axes[0]
        for e in np.asarray(elements)[flags > 0]:
            q = coords1[np.r_[e, e[0]]]
            ax.plot(q[:, 0], q[:, 1], "-", color="tab:red", lw=1.5)
        ax.set_title(ax.get_title() + f", red: >= {o.damage_critical:g}")
        fig.savefig(path, dpi=120)


def _membrane_plots(out: Path, result: Result, coords0, coords1, el, mesh_text: str, axes) -> None:
    """Load against tip displacement, deformed mesh, pressure on the deformed mesh."""
    from jaxform import plot

    h = result.history
    plot.load_displacement(
        h["tip_uy_mm"],
        h["force_N"],
        out / "load_displacement.png",
        f"{mesh_text}: load against tip displacement",
    )
    plot.deformed_mesh(
        coords0,
        coords1,
        el,
        out / "deformed_mesh.png",
        "initial and deformed mesh (displacements to scale)",
        axes,
    )
    stress = result.fields["stress"][-1].mean(axis=1)
    plot.cell_contours(
        coords1,
        el,
        -np.trace(stress, axis1=1, axis2=2) / 3.0,
        out / "pressure.png",
        "pressure (element mean)",
        "pressure [MPa]",
        axes,
    )


def _contact_plot(path: Path, result: Result) -> None:
    """Contact pressure and shear traction along the die at chosen strokes."""
    from jaxform import plot
    from jaxform.postprocess import contact_profile

    h, f = result.history, result.fields
    strokes = result.scene.settings.output.profile_strokes_mm or [
        q * h["stroke_mm"][-1] for q in (0.25, 0.5, 0.75, 1.0)
    ]
    profiles = {}
    for s in strokes:
        k = int(np.argmin(np.abs(h["stroke_mm"] - s)))
        profiles[float(h["stroke_mm"][k])] = contact_profile(
            result.scene_at(k),
            f["x"][k],
            f["slip_mm"][k],
            f["contact_status"][k],
            float(h["time_s"][k]),
        )
    plot.contact_profiles(profiles, path)


def animation_rows(n_rows: int, frames: int) -> np.ndarray:
    """The history rows an animation shows: at most ``frames``, evenly spread over the
    run, the first and last rows kept."""
    return np.unique(np.round(np.linspace(0, n_rows - 1, min(frames, n_rows))).astype(int))


def _animation(path: Path, result: Result, labels) -> int:
    """animation.gif: every chosen row's section (equivalent plastic strain, the dies at
    that row's time), from the fields the run stored."""
    from jaxform import plot

    h, f = result.history, result.fields
    rows = animation_rows(len(h["time_s"]), result.scene.settings.output.animation_frames)
    frames = []
    for k in rows:
        sc = result.scene_at(int(k))
        t = float(h["time_s"][k])
        frames.append((t, float(h["stroke_mm"][k]), positions(sc, f["x"][k]),
                       np.asarray(sc.mesh.elements), np.asarray(f["eqps"][k]).mean(axis=1),
                       die_outlines(sc, t)))  # fmt: skip
    return plot.animation(frames, path, "equivalent plastic strain", "equivalent plastic "
                          "strain [-]", labels)  # fmt: skip


def optimizer_settings(d):
    """The optimizer of a [design] section (:class:`jaxform.config.DesignConfig`): the
    optax loops (lbfgs, adam) or a sampling optimizer (lhs_rsm, cmaes)."""
    from jaxform.design import CmaEs, LhsRsm, OptimizerSettings

    if d.optimizer == "lhs_rsm":
        return LhsRsm(d.samples_per_variable, d.rsm_rounds, d.max_simulations, d.seed)
    if d.optimizer == "cmaes":
        return CmaEs(d.population, d.cmaes_sigma, d.max_simulations, d.seed)
    return OptimizerSettings(d.optimizer, d.iterations, d.learning_rate,
                             step_max_fraction=d.step_max_fraction)  # fmt: skip


def design_report(problem, hist) -> list[dict]:
    """The start design's and the best design's objective, every term of a weighted sum,
    the constraints' penalty and each constraint's value and margin: rows with quantity,
    start, best (:meth:`jaxform.design.problem.DesignProblem.report`)."""
    start, best = (problem.report(hist.designs[k]) for k in (0, hist.best))
    rows = [dict(quantity=k, start=start[k], best=best[k]) for k in start if k != "constraints"]
    for a, b in zip(start["constraints"], best["constraints"]):
        name = f"{a['group']}.{a['constraint']}"
        rows.append(dict(quantity=name, start=a["value"], best=b["value"]))
        rows.append(dict(quantity=f"{name}.limit", start=a["limit"], best=b["limit"]))
        rows.append(dict(quantity=f"{name}.margin", start=a["margin"], best=b["margin"]))
    return rows


def design_problem(config, overrides=(), forward_progress=None, single_program: bool = False):
    """(typed config, design problem) of a config's [design] section: the one entry point
    of ``jaxform design`` and experiments/design_comparison.py (``config`` and
    ``overrides`` as :func:`run_design` takes them; ``forward_progress`` the forward run's
    progress; ``single_program``: value() runs the gradient program, one compile)."""
    from jaxform.design import build_problem

    require_x64()
    cfg = _scene_config(config, overrides)
    enable_compilation_cache(cfg.solver.compilation_cache_dir)
    problem = build_problem(
        build_scene(cfg), progress=forward_progress, single_program=single_program
    )
    return cfg, problem


def run_design(
    config,
    overrides=(),
    out_dir: str | Path = "out/design",
    progress=None,
    forward_progress=None,
    announce=None,
):
    """Optimize the config's [design] problem; write the history and plots to out_dir.

    Arguments:
        config: the path of a TOML scene or a nested dict, or its typed Config;
            overrides: ``section.key=value``.
        out_dir: folder for design_history.csv, design_report.csv, objective.png,
            shapes.png, config.toml (as configured), designed.toml (at the best design)
            and, where a group moves a die, die_profiles.csv and .png
            (:func:`jaxform.designed_config.write_design_files`).
        progress: called after each optimizer iteration (iteration, objective,
            projected gradient norm, design), by a sampling optimizer after each run (runs,
            objective, best objective so far, design).
        forward_progress: the progress callback of the forward run that fixes the step
            schedule (:func:`jaxform.simulation.simulate`).
        announce: a line as each operation's forward run starts (a config with
            [[process.operation]] tables, :mod:`jaxform.process_design`) and where the
            designed config went.

    Returns:
        (the design problem, its optimization history)."""
    from jaxform.design import optimize
    from jaxform.designed_config import write_design_files
    from jaxform.plot import design_objective, design_shapes

    require_x64()
    loaded = _loaded(config, overrides, load_typed)
    if isinstance(loaded, Process):
        from jaxform.process_design import run_process_design

        return run_process_design(loaded, out_dir, progress, forward_progress, announce)
    cfg, problem = design_problem(loaded, (), forward_progress)
    scene = problem.scene
    d = cfg.design
    hist = optimize(problem, optimizer_settings(d), progress=progress)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    dump_config(cfg.to_dict(), out / "config.toml")
    write_design_files(cfg, problem, hist, out, announce)
    cols = hist.columns(problem)
    write_csv(out / "design_history.csv", cols)
    rows = design_report(problem, hist)
    with open(out / "design_report.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    unit = getattr(problem.objective, "unit", "-")
    design_objective(hist.objective, out / "objective.png", f"{d.objective} ({d.optimizer})", unit,
                     simulations=hist.simulations)  # fmt: skip
    # the start shapes on the initial mesh, the end shapes on the run's last mesh
    first = np.asarray(scene.mesh.elements)
    last = (
        first if problem.plan is None else np.asarray(problem.plan.segments[-1].scene.mesh.elements)
    )
    shapes = {}
    ends = (("initial design", hist.designs[0]), ("optimized", hist.designs[hist.best]))
    for name, design in ends:
        _, traj = problem.value(design)
        shapes[f"{name}, start"] = (np.asarray(problem.run_inputs(design)[0].coords), first)
        shapes[f"{name}, end"] = (np.asarray(traj.positions), last)
    best = hist.objective[hist.best]
    design_shapes(
        shapes,
        out / "shapes.png",
        f"shapes: {d.objective} {hist.objective[0]:.4g} -> {best:.4g} {unit}",
    )
    return problem, hist


def run_taylor(
    config, overrides=(), groups=None, h=(1.0, 0.5, 0.25, 0.125), progress=None,
    forward_progress=None, announce=None,
):  # fmt: skip
    """Taylor test of every design group of the scene (or the ones named); ``config`` as
    :func:`run_design` takes it; ``progress`` is called with (group, h, J) after each
    evaluation, ``forward_progress`` by the forward run that fixes the step schedule
    (:func:`jaxform.simulation.simulate`); a process config (:mod:`jaxform.process_design`)
    tests design.variables (or ``groups``, ``<operation>.<group>``), ``announce`` getting a
    line as each operation's forward run starts."""
    from jaxform.design import available_groups, build_problem, taylor_test

    require_x64()
    loaded = _loaded(config, overrides, load_typed)
    if isinstance(loaded, Process):
        from jaxform.process_design import run_process_taylor

        return run_process_taylor(loaded, groups, h, progress, forward_progress, announce)
    cfg = _scene_config(loaded, ())
    enable_compilation_cache(cfg.solver.compilation_cache_dir)
    scene = build_scene(cfg)
    names = available_groups(scene) if not groups else tuple(groups)
    problem = build_problem(scene, groups=names, progress=forward_progress)
    return taylor_test(problem, h=h, progress=progress)
