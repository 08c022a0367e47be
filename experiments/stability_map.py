"""Stability map: where each method fails on the upsetting scenes, against the time step.

    python experiments/stability_map.py [--quick] [--dts 0.01 0.03 0.1 0.3 1 3 10 20]
                                        [--elements q4 q1p0 q1q1] [--max-steps 200]
                                        [--out docs/figures]

Scenes: configs/upsetting_seed.toml (frictionless, q1q1 10 x 10 in the config) and
configs/upsetting_friction.toml (Coulomb mu = 0.3), both axisymmetric Al 1100-O at 673 K,
ram speed 0.075 mm/s (nominal strain rate 0.01 /s), 56.3 % reduction in 56.3 s.  For every
scene x formulation (``mesh.element``) x Newton with and without backtracking line search
(``solver.line_search``) x time step (``time.dt_s``), one run with the configured
``solver.max_cutbacks`` (6: a step may be halved down to dt/64).

Small steps: at dt = 0.01 s the full stroke is 5630 steps, so each run is capped at
``--max-steps`` steps (default 200): the reduction is set to min(56.3 %, max_steps x dt x
0.01 /s), i.e. dt = 0.1 s runs to 20 %, dt = 0.03 s to 6 %, dt = 0.01 s to 2 %.  The CSV
says which runs were capped (``end_stroke_mm``, ``capped``).

Recorded per run: converged to the (capped) end or not, the stroke reached, total cutbacks
(of the converged steps; a failing step's own cutbacks are in the failure message), mean
Newton iterations per load step (all sub-steps' iterations of a step, summed, over the
converged steps), the failure message, wall time (compile included for the first run of
each compiled program).  dt, the stroke and max_cutbacks are inputs of the compiled
program, so one program per scene x formulation x line search serves all time steps.

--quick: the friction scene on a 5 x 5 mesh, q1p0, both line-search settings, dt = 1 and
20 s (the test suite's compiled programs).

Writes stability_map.csv and stability_map.png (one panel per scene x line search;
formulations x time steps, colour = outcome and cutbacks, text = mean Newton iterations).
"""

from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

import numpy as np

import jaxform
from jaxform.config import load_config
from jaxform.scenes import build_scene
from jaxform.simulation import SimulationError, simulate

ROOT = Path(__file__).resolve().parents[1]
SCENES = {
    "frictionless": ROOT / "configs" / "upsetting_seed.toml",
    "coulomb 0.3": ROOT / "configs" / "upsetting_friction.toml",
}
ELEMENTS = ("q4", "q1p0", "q1q1")
DTS_S = (0.01, 0.03, 0.1, 0.3, 1.0, 3.0, 10.0, 20.0)
COLUMNS = (
    "scene",
    "element",
    "line_search",
    "mesh",
    "dt_s",
    "n_steps",
    "end_stroke_mm",
    "capped",
    "status",
    "reached_stroke_mm",
    "total_cutbacks",
    "mean_newton_per_step",
    "wall_s",
    "failure",
)


def capped_reduction(cfg: dict, dt_s: float, max_steps: int) -> float:
    """The configured reduction, or the one reached in max_steps steps of dt_s at the die
    speed (ram stroke = speed x t), whichever is smaller."""
    full = cfg["die"]["reduction"]
    by_steps = max_steps * dt_s * cfg["die"]["speed_mm_s"] / cfg["billet"]["height_mm"]
    return min(full, by_steps)


def one_run(
    config: Path, element: str, line_search: bool, dt_s: float, mesh: int | None, max_steps: int
) -> dict:
    """Run one (scene, element, line search, dt); never raises on a failed simulation."""
    base = load_config(config)
    mesh_over = [] if mesh is None else [f"mesh.nr={mesh}", f"mesh.nz={mesh}"]
    reduction = capped_reduction(base, dt_s, max_steps)
    cfg = load_config(
        config,
        [
            f"mesh.element={element}",
            f"solver.line_search={str(line_search).lower()}",
            f"time.dt_s={dt_s!r}",
            f"die.reduction={reduction!r}",
            "output.fields=false",
            "output.plots=false",
            *mesh_over,
        ],
    )
    scene = build_scene(cfg)
    t0 = time.perf_counter()
    failure = ""
    try:
        res = simulate(scene)
    except SimulationError as err:
        res, failure = err.result, str(err)
    wall = time.perf_counter() - t0
    h = res.history
    n_done = len(h["time_s"]) - 1
    height = cfg["billet"]["height_mm"]
    return dict(
        mesh=f"{cfg['mesh']['nr']}x{cfg['mesh']['nz']}",
        dt_s=dt_s,
        n_steps=scene.n_steps,
        end_stroke_mm=reduction * height,
        capped=reduction < base["die"]["reduction"],
        status="failed" if failure else "converged",
        reached_stroke_mm=float(h["stroke_mm"][-1]),
        total_cutbacks=int(h["cutbacks"].sum()),
        mean_newton_per_step=float(h["newton_iterations"][1:].sum() / max(n_done, 1)),
        wall_s=wall,
        failure=failure,
    )


def write_table(path: Path, rows: list[dict]) -> None:
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(COLUMNS)
        for r in rows:
            w.writerow([f"{r[k]:.6g}" if isinstance(r[k], float) else r[k] for k in COLUMNS])


def plot(rows: list[dict], path: Path) -> None:
    """One panel per scene x line search: formulations (rows) x dt (columns)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap

    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    searches = list(dict.fromkeys(r["line_search"] for r in rows))
    elements = [e for e in ELEMENTS if any(r["element"] == e for r in rows)]
    dts = sorted({r["dt_s"] for r in rows})
    cmap = ListedColormap(["#4daf4a", "#ffd92f", "#fc8d62", "#e41a1c"])
    fig, axes = plt.subplots(
        len(scenes),
        len(searches),
        squeeze=False,
        figsize=(
            max(9.0, 1.0 + 0.9 * len(dts) * len(searches)),
            0.6 + 1.3 * len(elements) * len(scenes),
        ),
    )
    for i, sc in enumerate(scenes):
        for j, ls in enumerate(searches):
            ax = axes[i][j]
            grid = np.full((len(elements), len(dts)), np.nan)
            for r in rows:
                if r["scene"] != sc or r["line_search"] != ls:
                    continue
                a, b = elements.index(r["element"]), dts.index(r["dt_s"])
                if r["status"] == "failed":
                    grid[a, b] = 3
                    text = f"fail\n@{r['reached_stroke_mm'] / r['end_stroke_mm']:.0%}"
                else:
                    c = r["total_cutbacks"]
                    grid[a, b] = 0 if c == 0 else (1 if c <= 5 else 2)
                    text = f"{r['mean_newton_per_step']:.1f}" + (f"\n{c} cb" if c else "")
                ax.text(b, a, text, ha="center", va="center", fontsize=7)
            ax.imshow(grid, cmap=cmap, vmin=-0.5, vmax=3.5, aspect="auto")
            capped = {r["dt_s"] for r in rows if r["capped"]}
            ax.set_xticks(
                range(len(dts)), [f"{d:g}*" if d in capped else f"{d:g}" for d in dts], fontsize=8
            )
            ax.set_yticks(range(len(elements)), elements)
            ax.set_xlabel("time step dt [s]")
            mesh = next(r["mesh"] for r in rows if r["scene"] == sc)
            ax.set_title(f"{sc} ({mesh}), line search {'on' if ls else 'off'}", fontsize=9)
    handles = [plt.Rectangle((0, 0), 1, 1, color=cmap(k)) for k in range(4)]
    fig.legend(
        handles,
        [
            "converged, no cutback",
            "converged, 1-5 cutbacks",
            "converged, > 5 cutbacks",
            "failed after max cutbacks",
        ],
        loc="lower center",
        ncol=4,
        fontsize=8,
    )
    fig.suptitle(
        "Upsetting, Al 1100-O 673 K: text = mean Newton iterations per step, "
        "cb = cutbacks; * = run capped to a shorter stroke",
        fontsize=9,
    )
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--quick", action="store_true", help="friction scene 4 x 4, q1p0, dt = 1 and 20 s (CI)"
    )
    ap.add_argument("--dts", type=float, nargs="+", default=list(DTS_S))
    ap.add_argument("--elements", nargs="+", default=list(ELEMENTS), choices=ELEMENTS)
    ap.add_argument(
        "--max-steps",
        type=int,
        default=200,
        help="cap on load steps per run (small dt: shorter stroke)",
    )
    ap.add_argument("--out", default="docs/figures")
    args = ap.parse_args(argv)
    jaxform.enable_x64()
    if args.quick:
        scenes, elements = {"coulomb 0.3": SCENES["coulomb 0.3"]}, ["q1p0"]
        dts, mesh = [1.0, 20.0], 5
    else:
        scenes, elements, dts, mesh = SCENES, args.elements, sorted(args.dts), None
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for name, path in scenes.items():
        for el in elements:
            for ls in (True, False):
                for dt in dts:
                    r = dict(
                        scene=name,
                        element=el,
                        line_search=ls,
                        **one_run(path, el, ls, dt, mesh, args.max_steps),
                    )
                    rows.append(r)
                    print(
                        f"{name:12s} {el:5s} LS {'on ' if ls else 'off'} dt {dt:6g} s "
                        f"({r['n_steps']:4d} steps to {r['end_stroke_mm']:.3g} mm): "
                        f"{r['status']:9s} at {r['reached_stroke_mm']:.3g} mm, "
                        f"{r['total_cutbacks']} cutbacks, {r['mean_newton_per_step']:.2f} "
                        f"its/step, {r['wall_s']:.1f} s {r['failure']}",
                        flush=True,
                    )
    write_table(out / "stability_map.csv", rows)
    plot(rows, out / "stability_map.png")
    print(f"wrote {out / 'stability_map.csv'} and {out / 'stability_map.png'}")
    return rows


if __name__ == "__main__":
    main()
