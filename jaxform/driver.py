"""`jaxform.run`: one call from a config to a history, fields and output files.

config (TOML path or dict) --load_config--> validated dict --build_scene--> Scene
  --simulate--> Result --write_outputs--> history.csv, config.toml, fields.pvd + VTUs, PNGs
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from jaxform.cache import enable_compilation_cache
from jaxform.config import dump_config, load_config
from jaxform.io import write_csv, write_vtu_series
from jaxform.postprocess import nodal_fields
from jaxform.scenes import build_scene
from jaxform.simulate import Result, SimulationError, simulate


def run(
    config,
    overrides=(),
    out_dir: str | Path | None = None,
    progress: Callable[[dict], None] | None = None,
) -> Result:
    """Validate, build and run a scene; write outputs to out_dir if given.

    Arguments:
        config: the path of a TOML scene or a nested dict (:func:`jaxform.config.load_config`).
        overrides: ``section.key=value`` strings applied to it.
        out_dir: folder for history.csv, config.toml, fields and plots (None: none written).
        progress: called after each compiled chunk with a dict (step, n_steps, time_s,
            stroke_mm, force_N, iterations, cutbacks).

    Returns:
        the :class:`jaxform.simulate.Result` (history and fields).

    Raises:
        ConfigError: a bad config.  SimulationError (with ``.result``): a step failed
        after all cutbacks; the outputs of the last converged state are written.
    """
    cfg = load_config(config, list(overrides))
    enable_compilation_cache(cfg.get("solver", {}).get("compilation_cache_dir"))
    scene = build_scene(cfg)
    try:
        result = simulate(scene, progress)
    except SimulationError as err:
        if out_dir is not None:
            write_outputs(out_dir, err.result)
        raise
    if out_dir is not None:
        write_outputs(out_dir, result)
    return result


def write_outputs(out_dir: str | Path, result: Result) -> None:
    from jaxform import plot

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    scene = result.scene
    cfg = scene.config
    h = result.history
    if scene.kind == "membrane":  # no die: the applied load and the tip displacement
        cols = {
            "time_s": h["time_s"],
            "dt_s": h["dt_s"],
            "load_N": h["force_N"],
            "tip_ux_mm": h["tip_ux_mm"],
            "tip_uy_mm": h["tip_uy_mm"],
            "newton_iterations": h["newton_iterations"],
            "cutbacks": h["cutbacks"],
        }
    else:
        cols = {
            k: h[k]
            for k in (
                "time_s",
                "dt_s",
                "stroke_mm",
                "force_N",
                "newton_iterations",
                "cutbacks",
                "friction_work_Nmm",
            )
        }
    cols.update({k: h[k] for k in ("inner_diameter_mm", "outer_diameter_mm", "die_fill") if k in h})
    if scene.rezone_quality > 0:  # worst element corner quality; 1 where the mesh was rezoned
        cols.update({k: h[k] for k in ("mesh_quality", "rezoned")})
    write_csv(out / "history.csv", cols)
    dump_config(cfg, out / "config.toml")
    if result.failure:
        (out / "FAILED.txt").write_text(result.failure + "\n")
    if cfg["output"]["fields"]:
        write_vtu_series(out, scene, result)
    if cfg["output"]["plots"]:
        coords0 = np.asarray(scene.inputs.coords)
        u, _, _ = nodal_fields(scene, result.fields["x"][-1])
        coords1 = coords0 + u
        el = np.asarray(scene.mesh.elements)
        mesh_text = f"{cfg['mesh']['element']}, {cfg['mesh']['nr']}x{cfg['mesh']['nz']}"
        axes = (
            ("r [mm]", "z [mm]")
            if cfg["mesh"]["geometry"] == "axisymmetric"
            else ("x [mm]", "y [mm]")
        )
        if scene.kind == "membrane":
            _membrane_plots(out, result, coords0, coords1, el, mesh_text, axes)
            return
        height = cfg[scene.kind]["depth_mm" if scene.kind == "block" else "height_mm"]
        red = 100.0 * h["stroke_mm"][-1] / height
        plot.force_stroke(
            h["stroke_mm"],
            h["force_N"],
            out / "force_stroke.png",
            f"{mesh_text}, friction {cfg['friction']['model']}",
        )
        plot.deformed_mesh(
            coords0,
            coords1,
            el,
            out / "deformed_mesh.png",
            f"initial and deformed mesh, {red:.1f} % reduction",
            axes,
        )
        plot.cell_contours(
            coords1,
            el,
            result.fields["eqps"][-1].mean(axis=1),
            out / "eqps.png",
            f"equivalent plastic strain, {red:.1f} % reduction",
            "equivalent plastic strain [-]",
            axes,
        )
        _contact_plot(out / "contact_profile.png", result)


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
    strokes = result.scene.config["output"]["profile_strokes_mm"] or [
        q * h["stroke_mm"][-1] for q in (0.25, 0.5, 0.75, 1.0)
    ]
    profiles = {}
    for s in strokes:
        k = int(np.argmin(np.abs(h["stroke_mm"] - s)))
        profiles[float(h["stroke_mm"][k])] = contact_profile(
            result.scene, f["x"][k], f["slip_mm"][k], f["contact_status"][k]
        )
    plot.contact_profiles(profiles, path)
