"""A process's files: the history over the process, the config, ParaView fields, plots.

out/history.csv            one row per converged step of every operation, columns
                           ``operation`` (1-based) and ``time_s`` over the process
out/operations.csv         one row per operation: start and end time, steps, peak
                           force, final stroke, trimmed volume
out/config.toml            the resolved config with its [[process.operation]] tables
out/fields.pvd, fields/    the ParaView time series over the whole process
out/process.png            force (and temperatures) over the process time
out/force_stroke_<k>_<name>.png   each forming operation's force against its stroke
out/eqps.png, temperature.png     the final part
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from jaxform.config import dump_config
from jaxform.io import write_csv, write_vtu_series
from jaxform.postprocess import nodal_temperature, positions
from jaxform.process import ProcessResult
from jaxform.process_config import process_document


def operation_table(result: ProcessResult) -> dict[str, np.ndarray]:
    """One row per operation run: index, start and end time (s), steps, peak force (N),
    final stroke (mm), trimmed volume (mm^3)."""
    names = ("operation", "start_s", "end_s", "steps", "peak_force_N", "stroke_mm", "trimmed_mm3")
    cols: dict[str, list] = {k: [] for k in names}
    for run in result.runs:
        h = run.result.history
        cols["operation"].append(run.operation.index)
        cols["start_s"].append(run.start_s)
        cols["end_s"].append(run.start_s + float(h["time_s"][-1]))
        cols["steps"].append(len(h["time_s"]) - 1)
        cols["peak_force_N"].append(float(np.max(h["force_N"])))
        cols["stroke_mm"].append(float(h["stroke_mm"][-1]))
        cols["trimmed_mm3"].append(run.trimmed_volume)
    return {k: np.asarray(v, dtype=float) for k, v in cols.items()}


def write_process_outputs(out_dir: str | Path, result: ProcessResult, doc: dict) -> None:
    """The files of a process run (module doc), also for a run that stopped: what it
    reached (FAILED.txt names why)."""
    from jaxform import plot

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / "history.csv", result.history)
    write_csv(out / "operations.csv", operation_table(result))
    dump_config(process_document(doc), out / "config.toml")
    if result.failure:
        (out / "FAILED.txt").write_text(result.failure + "\n")
    else:
        (out / "FAILED.txt").unlink(missing_ok=True)
    cfg = result.scene.settings
    if cfg.output.fields:
        write_vtu_series(out, result)
    if not cfg.output.plots:
        return
    names = {run.operation.index: run.operation.name for run in result.runs}
    plot.process_history(result.history, names, out / "process.png",
                         " -> ".join(names.values()))  # fmt: skip
    for run in result.runs:
        op, h = run.operation, run.result.history
        if not op.forming or len(h["time_s"]) < 2:
            continue
        plot.force_stroke(h["stroke_mm"], h["force_N"],
                          out / f"force_stroke_{op.index}_{_slug(op.name)}.png",
                          f"operation {op.index}: {op.name}")  # fmt: skip
    final = result.final_scene
    x = result.fields["x"][-1]
    pos = positions(final, x)
    elements = np.asarray(final.mesh.elements)
    axes = ("r [mm]", "z [mm]") if final.model.formulation.axisymmetric else ("x [mm]", "y [mm]")
    plot.cell_contours(pos, elements, np.asarray(result.fields["eqps"][-1]).mean(axis=1),
                       out / "eqps.png", "equivalent plastic strain, end of the process",
                       "equivalent plastic strain [-]", axes)  # fmt: skip
    temp = nodal_temperature(final, x)
    if temp is not None:
        plot.nodal_contours(pos, elements, temp, out / "temperature.png",
                            "temperature, end of the process", "temperature [K]", axes)  # fmt: skip


def _slug(name: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in name) or "op"


def summary(result: ProcessResult) -> list[str]:
    """One line per operation for the command line."""
    lines = []
    for run in result.runs:
        op, h = run.operation, run.result.history
        line = f"  {op.index} {op.name} ({op.kind}): {run.start_s:g} -> "
        line += f"{run.start_s + float(h['time_s'][-1]):g} s"
        if op.forming:
            line += f", peak force {float(np.max(h['force_N'])):.6g} N"
            line += f", stroke {float(h['stroke_mm'][-1]):.4g} mm"
        if run.trimmed_volume:
            line += f", trimmed {run.trimmed_volume:.6g} mm^3"
        for k, unit in (("die_fill", ""), ("flash_volume_mm3", " mm^3"),
                        ("mean_temperature_K", " K")):  # fmt: skip
            if k in h and not math.isnan(float(h[k][-1])):
                line += f", {k} {float(h[k][-1]):.6g}{unit}"
        lines.append(line)
    return lines
