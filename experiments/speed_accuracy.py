"""Speed against accuracy on the upsetting scenes: mesh size, formulation and time step.

    python experiments/speed_accuracy.py [--quick | --fine 80] [--out docs/figures]

Scenes (axisymmetric Al 1100-O at 673 K, 56.3 % reduction at 0.075 mm/s):
configs/upsetting_friction.toml (Coulomb mu = 0.3: bulge) and configs/upsetting_seed.toml
(frictionless: the deformation is exactly homogeneous, so the mesh adds no error and only
the time step does; the runs show it).

Runs (full mode):

* friction: q4, q1p0, q1q1 on 5x5, 10x10, 20x20, 40x40 (not q1p0, see below) at dt = 1 s;
  on 10x10 also dt = 4, 2, 0.5, 0.25 s; q1p0 and q1q1 also 20x20 at dt = 0.25 s.  80x80 (the issue's
  upper end) is a separate mode, --fine 80: on the 2-core machine one 80x80 q1q1 friction
  run takes ~240 s after a ~60 s compile, too long to repeat per formulation and step.
* frictionless: q4, q1p0, q1q1 on 5x5 and 10x10 at dt = 4, 2, 1, 0.5, 0.25 s; q1q1 also
  20x20 at dt = 1 s.

Errors, against a reference (see below):

* force: relative L2 error of the ram force over the stroke, sqrt(sum (F - F_ref)^2 /
  sum F_ref^2), at the strokes of t = 4, 8, ..., 56 s and the end (every dt here divides
  4 s, so these are converged steps of every run: no interpolation error);
* shape (friction): maximum deviation of the final free-side profile r(z) from the
  reference's, at 11 heights from the mid-plane to the die, over the reference's bulge
  (maximum) radius; frictionless: the same (the side stays straight).

Reference.  Friction: q1p0, Richardson extrapolation in the mesh (5x5, 10x10, 20x20 at
dt = 1 s; q1p0 40x40 fails at 26.5 s with dt = 1 s, Newton not converging after 6
cutbacks) plus Richardson extrapolation in the time step (dt = 1, 0.5, 0.25 s on 10x10),
the two corrections added (errors in h and dt assumed additive).  Each extrapolation uses
the observed order p = log2(|d1| / |d2|) of the successive differences; it is used only
where the convergence is monotone (d1 . d2 > 0 and |d2| < |d1|), else the finest run is
the reference; the script prints which.  Frictionless: the deformation is homogeneous, so
the reference is the material point (jaxform.materialpoint, same law, ram-speed loading)
with steps of 0.04, 0.02, 0.01 s, Richardson-extrapolated the same way.

Wall time: the run after compilation (one warm-up run of 8 steps per compiled program:
scene x formulation x mesh; dt and the stroke are inputs of the compiled program), build of
the scene excluded, on whatever machine this runs (2 shared cores for the README numbers).

--quick: friction, q1p0, 5x5 / 10x10 / 20x20 at dt = 1 s; reference = the mesh
extrapolation of those three (no time-step correction: the errors are mesh errors at
dt = 1 s).

Writes speed_accuracy.csv (one row per run; rows with mesh "reference" hold the
reference's construction) and speed_accuracy.png (error against wall time, Pareto front
marked), and prints the cheapest choice for a force and shape error of 5 %, 1 %, 0.2 %.
"""

from __future__ import annotations

import argparse
import csv
import math
import pickle
import time
from pathlib import Path

import numpy as np

import jaxform
from jaxform.config import load_config
from jaxform.postprocess import positions
from jaxform.scenes import build_scene
from jaxform.simulation import SimulationError, simulate

ROOT = Path(__file__).resolve().parents[1]
SCENES = {
    "coulomb 0.3": ROOT / "configs" / "upsetting_friction.toml",
    "frictionless": ROOT / "configs" / "upsetting_seed.toml",
}
ELEMENTS = ("q4", "q1p0", "q1q1")
TARGETS = (0.05, 0.01, 0.002)
COMPARE_EVERY_S = 4.0  # common comparison times: multiples of this and the end
PROFILE_POINTS = 11
COLUMNS = (
    "scene",
    "element",
    "mesh",
    "dt_s",
    "wall_s",
    "steps",
    "newton_iterations",
    "force_error",
    "force_max_error",
    "shape_error",
    "final_force_N",
    "bulge_radius_mm",
    "failure",
)


def full_plan() -> list[tuple]:
    """(scene, element, elements per side, dt_s) of the full study."""
    plan = []
    for el in ELEMENTS:
        # q1p0 40x40 at dt = 1 s fails at 26.5 s (Newton, 6 cutbacks): left out
        plan += [
            ("coulomb 0.3", el, n, 1.0) for n in ((5, 10, 20) if el == "q1p0" else (5, 10, 20, 40))
        ]
        plan += [("coulomb 0.3", el, 10, dt) for dt in (4.0, 2.0, 0.5, 0.25)]
        if el != "q4":
            plan.append(("coulomb 0.3", el, 20, 0.25))
        plan += [("frictionless", el, n, dt) for n in (5, 10) for dt in (4.0, 2.0, 1.0, 0.5, 0.25)]
    plan.append(("frictionless", "q1q1", 20, 1.0))
    return plan


def full_references() -> dict:
    """scene -> (element, (meshes at dt_mesh, dt_mesh) or None, (dts at mesh_dt, mesh_dt))
    or "material point" (homogeneous frictionless upsetting)."""
    return {
        "coulomb 0.3": ("q1p0", ((5, 10, 20), 1.0), ((1.0, 0.5, 0.25), 10)),
        "frictionless": "material point",
    }


def fine_plan(sizes) -> list[tuple]:
    """--fine: the friction reference's runs plus q1q1 (the best friction element on fine
    meshes) at each of ``sizes`` x ``sizes`` with dt = 1 s: the 80x80 end of the issue's range
    without re-running the whole study."""
    (el, (meshes, dt_mesh), (dts, mesh_dt)) = full_references()["coulomb 0.3"]
    plan = [("coulomb 0.3", el, n, dt_mesh) for n in meshes]
    plan += [("coulomb 0.3", el, mesh_dt, dt) for dt in dts if dt != dt_mesh]
    return plan + [("coulomb 0.3", "q1q1", n, 1.0) for n in sizes]


# the quick mode's meshes: 4x4 fails at dt = 1 s near the end of the stroke (step 55 of 57,
# Newton after 6 cutbacks, with jax 0.10); 5x5 is the full study's coarsest
QUICK_MESHES = (5, 10, 20)


def quick_plan() -> list[tuple]:
    return [("coulomb 0.3", "q1p0", n, 1.0) for n in QUICK_MESHES]


def quick_references() -> dict:
    return {"coulomb 0.3": ("q1p0", (QUICK_MESHES, 1.0), None)}


def config_for(scene: str, element: str, n: int, dt_s: float, reduction: float | None = None):
    over = [
        f"mesh.element={element}",
        f"mesh.nr={n}",
        f"mesh.nz={n}",
        f"time.dt_s={dt_s!r}",
        "output.fields=false",
        "output.plots=false",
    ]
    if reduction is not None:
        over.append(f"die.reduction={reduction!r}")
    return load_config(SCENES[scene], over)


def side_profile(scene, x) -> np.ndarray:
    """Current radius of the free side at PROFILE_POINTS heights from the mid-plane to the
    highest side node (mm), interpolated linearly between the side nodes."""
    pos = positions(scene, x)[scene.mesh.node_sets["side"]]
    order = np.argsort(pos[:, 1])
    z, r = pos[order, 1], pos[order, 0]
    return np.interp(np.linspace(0.0, z[-1], PROFILE_POINTS), z, r)


def timed_run(scene_name: str, element: str, n: int, dt_s: float, warmed: set) -> dict:
    """One run after a warm-up (compile) of its program; force at the comparison times."""
    key = (scene_name, element, n)
    if key not in warmed:  # same compiled program: a short stroke of 8 steps
        base = config_for(scene_name, element, n, dt_s)
        short = min(
            base["die"]["reduction"],
            8 * dt_s * base["die"]["speed_mm_s"] / base["billet"]["height_mm"],
        )
        try:
            simulate(build_scene(config_for(scene_name, element, n, dt_s, short)))
        except SimulationError:
            pass  # compiled all the same; the timed run records the failure
        warmed.add(key)
    scene = build_scene(config_for(scene_name, element, n, dt_s))
    t0 = time.perf_counter()
    failure = ""
    try:
        res = simulate(scene)
    except SimulationError as err:  # kept in the table, left out of errors and choices
        res, failure = err.result, str(err)
    wall = time.perf_counter() - t0
    h = res.history
    t_cmp = np.append(np.arange(COMPARE_EVERY_S, scene.t_end - 1e-9, COMPARE_EVERY_S), scene.t_end)
    return dict(
        scene=scene_name,
        element=element,
        mesh=f"{n}x{n}",
        n=n,
        dt_s=dt_s,
        wall_s=wall,
        steps=len(h["time_s"]) - 1,
        newton_iterations=int(h["newton_iterations"].sum()),
        force=None if failure else np.interp(t_cmp, h["time_s"], h["force_N"]),
        profile=None if failure else side_profile(scene, res.fields["x"][-1]),
        failure=failure,
    )


def richardson(v1: np.ndarray, v2: np.ndarray, v3: np.ndarray) -> tuple[np.ndarray, float, bool]:
    """Extrapolation of three results on successively halved h (or dt).

    Returns (value, observed order p, monotone).  p = log2(|v2 - v1| / |v3 - v2|) over
    the whole vector; monotone when the two differences point the same way
    ((v2 - v1) . (v3 - v2) > 0) and shrink.  Not monotone: (v3, nan, False)."""
    d1, d2 = v2 - v1, v3 - v2
    n1, n2 = float(np.linalg.norm(d1)), float(np.linalg.norm(d2))
    if n2 == 0.0:
        return v3, math.inf, True
    if float(np.dot(d1, d2)) <= 0.0 or n2 >= n1:
        return v3, math.nan, False
    p = math.log2(n1 / n2)
    return v3 + d2 / (2.0**p - 1.0), p, True


def material_point_reference(scene_name: str) -> tuple[dict, list[str]]:
    """Homogeneous frictionless upsetting: force = axial stress x current area of the
    material point (jaxform.materialpoint, the ram-speed loading), Richardson-extrapolated
    over steps of 0.04, 0.02, 0.01 s; the side profile is straight at R0 lam_r."""
    from jaxform.materialpoint import Ram, uniaxial_compression
    from jaxform.materials import load_material

    cfg = config_for(scene_name, "q1q1", 1, 1.0)
    b, d = cfg["billet"], cfg["die"]
    h0, r0 = b["height_mm"], 0.5 * b["diameter_mm"]
    t_end = d["reduction"] * h0 / d["speed_mm_s"]
    t_cmp = np.append(np.arange(COMPARE_EVERY_S, t_end - 1e-9, COMPARE_EVERY_S), t_end)
    law, params = load_material(cfg["material"]["preset"])
    forces, radii = [], []
    for dt in (0.04, 0.02, 0.01):
        times = np.append(np.arange(1, int(np.ceil(t_end / dt - 1e-9))) * dt, t_end)
        out = uniaxial_compression(
            law,
            params,
            final_strain=0.0,
            n_steps=0,
            ram=Ram(d["speed_mm_s"], h0),
            alpha=cfg["time"]["alpha"],
            times_s=times,
        )
        t = np.asarray(out["time_s"])
        lam_r = np.asarray(out["lateral_stretch"])
        force = np.asarray(out["stress_MPa"]) * np.pi * (r0 * lam_r) ** 2
        forces.append(np.interp(t_cmp, t, force))
        radii.append(np.full(PROFILE_POINTS, r0 * lam_r[-1]))
    f, p, mono = richardson(*forces)
    r, _, _ = richardson(*radii)
    note = f"{scene_name}: material point (jaxform.materialpoint), dt 0.04/0.02/0.01 s: " + (
        f"monotone, observed order {p:.2f}, extrapolated"
        if mono
        else "not monotone: finest dt used"
    )
    return {"force": f, "profile": r}, [note]


def reference(runs: dict, scene: str, spec) -> tuple[dict, list[str]]:
    """Reference force curve and side profile of a scene, and lines saying how."""
    if spec == "material point":
        return material_point_reference(scene)
    element, mesh_spec, dt_spec = spec
    notes = []
    quantity = {}
    for q in ("force", "profile"):
        base = None
        corr = 0.0
        if mesh_spec is not None:
            meshes, dt = mesh_spec
            vals = [runs[(scene, element, n, dt)][q] for n in meshes]
            ext, p, mono = richardson(*vals)
            base = ext
            notes.append(
                f"{scene}, {q}: mesh {'x'.join(map(str, meshes))} at dt = {dt:g} s, "
                f"{element}: "
                + (
                    f"monotone, observed order {p:.2f}, extrapolated"
                    if mono
                    else "not monotone: finest mesh used"
                )
            )
        if dt_spec is not None:
            dts, n = dt_spec
            vals = [runs[(scene, element, n, dt)][q] for dt in dts]
            ext, p, mono = richardson(*vals)
            notes.append(
                f"{scene}, {q}: dt {'/'.join(f'{d:g}' for d in dts)} s on {n}x{n}, "
                f"{element}: "
                + (
                    f"monotone, observed order {p:.2f}, extrapolated"
                    if mono
                    else "not monotone: finest dt used"
                )
            )
            if base is None:
                base = ext
            else:  # additive: the time-step correction relative to the mesh runs' dt
                corr = ext - runs[(scene, element, n, mesh_spec[1])][q]
        quantity[q] = base + corr
    return quantity, notes


def errors(run: dict, ref: dict) -> dict:
    """Relative errors against the reference (inf for a failed run)."""
    if run["failure"]:
        return dict(
            force_error=math.inf,
            force_max_error=math.inf,
            shape_error=math.inf,
            final_force_N=math.nan,
            bulge_radius_mm=math.nan,
        )
    f, fr = run["force"], ref["force"]
    return dict(
        force_error=float(np.linalg.norm(f - fr) / np.linalg.norm(fr)),
        force_max_error=float(np.max(np.abs(f - fr) / np.abs(fr))),
        shape_error=float(np.max(np.abs(run["profile"] - ref["profile"])) / np.max(ref["profile"])),
        final_force_N=float(f[-1]),
        bulge_radius_mm=float(np.max(run["profile"])),
    )


def pareto(rows: list[dict], key: str) -> list[dict]:
    """Rows not dominated in (wall_s, key): no other row is both faster and more accurate."""
    front, best = [], math.inf
    for r in sorted(rows, key=lambda r: (r["wall_s"], r[key])):
        if r[key] < best:
            front.append(r)
            best = r[key]
    return front


def choices(rows: list[dict], targets=TARGETS) -> list[dict]:
    """Per scene and target: the fastest run whose force and shape errors are both within it."""
    out = []
    for scene in dict.fromkeys(r["scene"] for r in rows):
        sel = [r for r in rows if r["scene"] == scene]
        for tol in targets:
            ok = [r for r in sel if max(r["force_error"], r["shape_error"]) <= tol]
            best = min(ok, key=lambda r: r["wall_s"]) if ok else None
            out.append(dict(scene=scene, target=tol, run=best))
    return out


def write_table(path: Path, rows: list[dict], notes: list[str]) -> None:
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(COLUMNS)
        for r in rows:
            w.writerow([f"{r[k]:.6g}" if isinstance(r[k], float) else r[k] for k in COLUMNS])
        for line in notes:
            w.writerow(["# " + line])


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    fig, axes = plt.subplots(len(scenes), 2, figsize=(11, 4.2 * len(scenes)), squeeze=False)
    colours = {"q4": "tab:red", "q1p0": "tab:blue", "q1q1": "tab:green"}
    markers = {4: "v", 5: "v", 8: "o", 10: "o", 16: "s", 20: "s", 40: "D", 80: "*"}
    for i, scene in enumerate(scenes):
        sel = [r for r in rows if r["scene"] == scene]
        for j, (key, label) in enumerate(
            (
                ("force_error", "force-stroke error (rel. L2)"),
                ("shape_error", "final side-profile error (max dev. / bulge radius)"),
            )
        ):
            ax = axes[i][j]
            shown = [r for r in sel if r[key] > 0.0]  # an error of 0: the reference itself
            for r in shown:
                ax.loglog(
                    r["wall_s"],
                    r[key],
                    markers.get(r["n"], "o"),
                    color=colours[r["element"]],
                    mfc="none" if r["dt_s"] != 1.0 else None,
                    ms=4 + 2 * math.log2(4.0 / r["dt_s"] + 1.0),
                )
            front = pareto(shown, key)
            ax.loglog(
                [r["wall_s"] for r in front],
                [r[key] for r in front],
                "k--",
                lw=1,
                drawstyle="steps-post",
                label="Pareto front",
            )
            for r in front:
                ax.annotate(
                    f"{r['element']} {r['mesh']} dt {r['dt_s']:g}",
                    (r["wall_s"], r[key]),
                    fontsize=6,
                    xytext=(3, 3),
                    textcoords="offset points",
                )
            for tol in TARGETS:
                ax.axhline(tol, color="0.7", lw=0.8, ls=":")
            ax.set_xlabel("wall time after compile [s]")
            ax.set_ylabel(label)
            ax.set_title(scene, fontsize=9)
            ax.grid(True, which="both", alpha=0.2)
        handles = [
            plt.Line2D([], [], color=c, marker="o", ls="", label=e) for e, c in colours.items()
        ]
        handles += [
            plt.Line2D([], [], color="k", marker=m, ls="", mfc="none", label=f"{n}x{n}")
            for n, m in markers.items()
            if any(r["n"] == n for r in sel)
        ]
        handles.append(plt.Line2D([], [], color="k", ls="--", label="Pareto front"))
        axes[i][0].legend(
            handles=handles, fontsize=7, title="filled: dt = 1 s; size ~ 1/dt", title_fontsize=7
        )
    fig.suptitle(
        "Upsetting, Al 1100-O 673 K: error against wall time (mesh, formulation, dt)", fontsize=10
    )
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--quick", action="store_true", help="friction, q1p0, 5x5/10x10/20x20 at dt = 1 s (CI)"
    )
    ap.add_argument(
        "--fine",
        type=int,
        nargs="+",
        default=[],
        help="only the friction reference and q1q1 on these meshes (e.g. 80), dt 1 s",
    )
    ap.add_argument("--out", default="docs/figures")
    ap.add_argument(
        "--runs-file",
        default="",
        help="pickle of the runs: reused if it exists, else written after the runs",
    )
    args = ap.parse_args(argv)
    jaxform.enable_x64()
    if args.quick:
        plan, refs = quick_plan(), quick_references()
    elif args.fine:
        plan, refs = fine_plan(args.fine), {"coulomb 0.3": full_references()["coulomb 0.3"]}
    else:
        plan, refs = full_plan(), full_references()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    runs, warmed = {}, set()
    cache = Path(args.runs_file) if args.runs_file else None
    if cache is not None and cache.is_file():
        with open(cache, "rb") as fh:
            runs = pickle.load(fh)
    for scene, el, n, dt in plan:
        if (scene, el, n, dt) in runs:
            continue
        r = timed_run(scene, el, n, dt, warmed)
        runs[(scene, el, n, dt)] = r
        print(
            f"{scene:12s} {el:5s} {n:3d}x{n:<3d} dt {dt:5g} s: {r['wall_s']:7.2f} s, "
            f"{r['steps']} steps, {r['newton_iterations']} Newton its, "
            + (
                f"FAILED: {r['failure']}"
                if r["failure"]
                else f"final force {r['force'][-1]:.2f} N, "
                f"bulge radius {np.max(r['profile']):.4f} mm"
            ),
            flush=True,
        )
    if cache is not None:
        with open(cache, "wb") as fh:
            pickle.dump(runs, fh)
    rows, notes = [], []
    for scene, spec in refs.items():
        ref, how = reference(runs, scene, spec)
        notes += how
        for line in how:
            print("reference:", line)
        for r in (v for k, v in runs.items() if k[0] == scene):
            rows.append(dict(r, **errors(r, ref)))
        rows.append(
            dict(
                scene=scene,
                element=spec if isinstance(spec, str) else spec[0],
                mesh="reference",
                n=0,
                dt_s=0.0,
                wall_s=0.0,
                steps=0,
                newton_iterations=0,
                force_error=0.0,
                force_max_error=0.0,
                shape_error=0.0,
                final_force_N=float(ref["force"][-1]),
                bulge_radius_mm=float(np.max(ref["profile"])),
                failure="",
            )
        )
    measured = [r for r in rows if r["mesh"] != "reference" and not r["failure"]]
    for r in rows:
        if r["mesh"] == "reference":
            continue
        print(
            f"{r['scene']:12s} {r['element']:5s} {r['mesh']:>6s} dt {r['dt_s']:5g} s: "
            f"force error {r['force_error']:.2e} (max {r['force_max_error']:.2e}), shape "
            f"error {r['shape_error']:.2e}, {r['wall_s']:.2f} s"
        )
    picks = choices(measured)
    print("\ncheapest run with force and shape errors within the target:")
    for c in picks:
        r = c["run"]
        text = (
            "none of the runs"
            if r is None
            else f"{r['element']} {r['mesh']} dt = {r['dt_s']:g} s: {r['wall_s']:.2f} s, force "
            f"{r['force_error']:.2e}, shape {r['shape_error']:.2e}"
        )
        print(f"  {c['scene']:12s} {c['target']:6.1%}: {text}")
    write_table(out / "speed_accuracy.csv", rows, notes)
    plot(measured, out / "speed_accuracy.png")
    print(f"wrote {out / 'speed_accuracy.csv'} and {out / 'speed_accuracy.png'}")
    return {"rows": rows, "choices": picks, "notes": notes}


if __name__ == "__main__":
    main()
