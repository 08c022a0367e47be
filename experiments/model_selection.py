"""Model selection: what a simpler model costs in accuracy on the upsetting scenes.

    python experiments/model_selection.py [--out docs/figures]

Three comparisons (numbers for the README's "Model selection" section):

1. **J2 instead of Anand.**  The frictionless seed scene is homogeneous (README: the force
   equals the material point's for every mesh and formulation), so a 5 x 5 q1q1 run gives
   the flow curve: true axial stress sigma = F / (pi R0^2 H0 / H) (volume kept; the elastic
   volume change, ~sigma/K ~ 5e-4, is neglected) against the true strain ln(H0 / H).  A J2
   law with linear hardening, sigma = sigma_y0 + H_mod ln(H0/H), is fitted by least squares
   to it at the seed's ram speed (0.075 mm/s, nominal rate 0.01 /s), written as a material
   TOML into the output folder, and both laws are run at the seed speed and at 10 x and
   0.1 x that speed (dt scaled with it: the same strain per step).  Error: relative L2
   of the force over the stroke (at the strokes of every 4th step, the end included).
2. **Plane strain instead of axisymmetry** (``mesh.geometry``): the same half-section as a
   plane-strain block, frictionless (5 x 5 q1q1) and Coulomb 0.3 (10 x 10 q1p0, dt = 0.5 s:
   at the config's 1 s the plane-strain run fails at 31 s, Newton not converging after 6
   cutbacks).  Measured:
   the mean die pressure at the end, force over the contact measure (axisymmetric:
   pi r_c^2; plane strain: the half-width x_c, as the force is per mm of depth of the half
   model), with r_c, x_c = the outermost node touching the die (within 1e-6 mm).  The
   friction factor (pressure with friction / without) of each geometry compares how far
   plane strain misjudges friction.
3. **Half model instead of the full width** (plane strain, ``--part symmetry``): the
   plane-strain block of part 2 with Coulomb 0.3 (10 x 10 q1p0, dt = 0.5 s) is a quarter
   of the cross-section (u_x = 0 on x = 0, u_y = 0 on the mid-plane).  The same block at
   full width (20 x 10 elements of the same size, x in [-R, R]; u_x = 0 only at the centre
   node of the mid-plane, which removes the rigid-body mode and nothing else) is written
   as a gmsh file (``jaxform.mesh.write_mesh``) and run through ``mesh.file``.  Compared:
   the force (full = 2 x half, per mm of depth) over the run, the final free-surface
   positions (each half-model node against its twin in the full model), the
   left-right asymmetry of the full model, the unknowns, and the wall time of a run
   after compilation.  Then the case the half model cannot represent: the same full
   block under a top die tilted by ``TILT_DEG`` (touching first at x = +R): force
   against the parallel die and the difference between the right and left bulge.
   The half-height (mid-plane) symmetry is kept in every run: a full-height billet needs
   a second, bottom die, which jaxform does not have (one rigid die per scene).

Writes model_selection.csv (quantity, value) and model_selection_j2_fit.toml (parts 1, 2)
and model_selection_symmetry.csv (part 3).
"""

from __future__ import annotations

import argparse
import csv
import math
import tempfile
import time
from pathlib import Path

import numpy as np

import jaxform
from jaxform.config import load_config
from jaxform.materials import load_material
from jaxform.mesh import Mesh, rectangle, write_mesh
from jaxform.postprocess import positions
from jaxform.scenes import build_scene
from jaxform.simulation import simulate

ROOT = Path(__file__).resolve().parents[1]
SEED = ROOT / "configs" / "upsetting_seed.toml"
FRICTION = ROOT / "configs" / "upsetting_friction.toml"
SEED_SPEED_MM_S = 0.075
SPEED_FACTORS = (0.1, 1.0, 10.0)
PLANE_FRICTION = ["mesh.nr=10", "mesh.nz=10", "time.dt_s=0.5", "mesh.geometry=plane_strain"]
TILT_DEG = 1.0


def run(config: Path, overrides: list[str]):
    cfg = load_config(config, ["output.fields=false", "output.plots=false", *overrides])
    scene = build_scene(cfg)
    return scene, simulate(scene)


def flow_curve(scene, res) -> tuple[np.ndarray, np.ndarray]:
    """(true strain, true axial stress MPa) of a homogeneous axisymmetric compression."""
    b = scene.workpiece
    r0, h0 = 0.5 * b.diameter_mm, b.height_mm
    h = h0 - res.history["stroke_mm"]
    area = math.pi * r0**2 * h0 / h
    return np.log(h0 / h)[1:], (res.history["force_N"] / area)[1:]


def fit_j2(strain: np.ndarray, stress: np.ndarray) -> tuple[float, float]:
    """Least-squares sigma_y0 + H_mod * strain (MPa)."""
    a = np.stack([np.ones_like(strain), strain], axis=1)
    (sy, hm), *_ = np.linalg.lstsq(a, stress, rcond=None)
    return float(sy), float(hm)


def write_j2(path: Path, sigma_y0: float, h_mod: float) -> None:
    _, params = load_material("al1100_673K")
    path.write_text(
        "# J2 with linear hardening fitted (least squares) to the Anand flow curve of the seed\n"
        "# scene at 0.075 mm/s (experiments/model_selection.py); moduli of al1100_673K.\n"
        'law = "j2"\ndescription = "J2 fit to Al 1100-O 673 K at a nominal rate of 0.01 /s"\n\n'
        f"[params]\nG_MPa = {float(params.G_MPa)!r}\nK_MPa = {float(params.K_MPa)!r}\n"
        f"sigma_y0_MPa = {sigma_y0!r}\nH_MPa = {h_mod!r}\n"
    )


def force_on_strokes(res, strokes: np.ndarray) -> np.ndarray:
    return np.interp(strokes, res.history["stroke_mm"], res.history["force_N"])


def rel_l2(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def mean_pressure(scene, res) -> float:
    """Force over the contact measure (MPa) at the end of the run."""
    pos = positions(scene, res.fields["x"][-1])
    top = pos[scene.mesh.node_sets["top"], 1].max()
    rc = pos[pos[:, 1] >= top - 1e-6, 0].max()
    axi = scene.model.formulation.axisymmetric
    return float(res.history["force_N"][-1] / (math.pi * rc**2 if axi else rc))


def full_width_mesh(radius: float, half_height: float, nr: int, nz: int) -> Mesh:
    """The block [-R, R] x [0, H/2] in 2 nr x nz elements (the half model's, mirrored);
    u_x is held only at the centre node of the mid-plane (set ``axis``, a point group)."""
    r = rectangle(2.0 * radius, half_height, 2 * nr, nz, origin=(-radius, 0.0))
    centre = np.flatnonzero(np.hypot(r.coords[:, 0], r.coords[:, 1]) < 1e-9 * radius)
    side = np.concatenate([r.facet_sets["left"], r.facet_sets["right"]])
    return Mesh(
        r.coords,
        r.elements,
        {
            "symmetry": r.node_sets["bottom"],
            "top": r.node_sets["top"],
            "side": np.unique(side),
            "axis": centre,
        },
        {"symmetry": r.facet_sets["bottom"], "top": r.facet_sets["top"], "side": side},
    )


def timed_run(config: Path, overrides: list[str]):
    """(scene, result, wall time of a second run after the first one compiled)."""
    scene, _ = run(config, overrides)
    t0 = time.perf_counter()
    res = simulate(scene)
    return scene, res, time.perf_counter() - t0


def symmetry_study(out: Path) -> dict[str, float]:
    """Part 3: half model against the full width, and a tilted die (module docstring)."""
    cfg = load_config(FRICTION, PLANE_FRICTION)
    radius, half_h = 0.5 * cfg["billet"]["diameter_mm"], 0.5 * cfg["billet"]["height_mm"]
    tilt = math.tan(math.radians(TILT_DEG))
    w = 20.0  # tilted profile's half-length (mm), beyond the final half-width
    tilted = [[-w, half_h + (radius + w) * tilt], [w, half_h - (w - radius) * tilt]]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "full_width.msh"
        write_mesh(path, full_width_mesh(radius, half_h, cfg["mesh"]["nr"], cfg["mesh"]["nz"]))
        full = PLANE_FRICTION + [f"mesh.file={path}"]
        half_sc, half, t_half = timed_run(FRICTION, PLANE_FRICTION)
        full_sc, whole, t_full = timed_run(FRICTION, full)
        # the tilted die touches first at x = +R: the half model cannot represent it
        tilt_sc, tilted_res, t_tilt = timed_run(FRICTION, full + [f"die.profile_mm={tilted!r}"])
    n = min(len(half.history["force_N"]), len(whole.history["force_N"]))
    f_half, f_full = 2.0 * half.history["force_N"][1:n], whole.history["force_N"][1:n]
    same_t = np.allclose(half.history["time_s"][:n], whole.history["time_s"][:n], atol=1e-12)
    # final free surface: each half-model node against the full-model node it started at
    p_half = positions(half_sc, half.fields["x"][-1])
    p_full = positions(full_sc, whole.fields["x"][-1])
    x0_half, x0_full = np.asarray(half_sc.mesh.coords), np.asarray(full_sc.mesh.coords)
    twin = [int(np.argmin(np.sum((x0_full - x) ** 2, axis=1))) for x in x0_half]
    mirror = [int(np.argmin(np.sum((x0_full - x * [-1.0, 1.0]) ** 2, axis=1))) for x in x0_full]
    shape_diff = float(np.max(np.linalg.norm(p_full[twin] - p_half, axis=1)))
    asym = float(np.max(np.linalg.norm(p_full - p_full[mirror] * [-1.0, 1.0], axis=1)))
    v = {
        "half_unknowns": half_sc.model.layout.n_dofs,
        "full_unknowns": full_sc.model.layout.n_dofs,
        "same_time_steps": float(same_t),
        "steps_half": len(half.history["time_s"]) - 1,
        "steps_full": len(whole.history["time_s"]) - 1,
        "force_max_rel_diff_full_vs_2half": float(np.max(np.abs(f_full - f_half) / f_half)),
        "final_force_N_per_mm_half_x2": float(2.0 * half.history["force_N"][-1]),
        "final_force_N_per_mm_full": float(whole.history["force_N"][-1]),
        "final_shape_max_diff_mm": shape_diff,
        "full_left_right_asymmetry_mm": asym,
        "run_time_s_half": t_half,
        "run_time_s_full": t_full,
        "newton_its_half": float(np.sum(half.history["newton_iterations"])),
        "newton_its_full": float(np.sum(whole.history["newton_iterations"])),
    }
    p_tilt = positions(tilt_sc, tilted_res.fields["x"][-1])
    side = full_sc.mesh.node_sets["side"]
    right = side[x0_full[side, 0] > 0]
    left = side[x0_full[side, 0] < 0]
    v.update(
        {
            "tilt_deg": TILT_DEG,
            "run_time_s_tilt": t_tilt,
            "newton_its_tilt": float(np.sum(tilted_res.history["newton_iterations"])),
            "tilt_final_force_N_per_mm": float(tilted_res.history["force_N"][-1]),
            "tilt_force_rel_diff_vs_parallel": float(
                tilted_res.history["force_N"][-1] / whole.history["force_N"][-1] - 1.0
            ),
            "tilt_right_bulge_mm": float(p_tilt[right, 0].max()),
            "tilt_left_bulge_mm": float(-p_tilt[left, 0].min()),
            "parallel_bulge_mm": float(p_full[right, 0].max()),
            "tilt_final_stroke_mm": float(tilted_res.history["stroke_mm"][-1]),
        }
    )
    with open(out / "model_selection_symmetry.csv", "w", newline="") as fh:
        wr = csv.writer(fh)
        wr.writerow(["quantity", "value"])
        for k, val in v.items():
            wr.writerow([k, f"{val:.6g}"])
    for k, val in v.items():
        print(f"{k}: {val:.6g}")
    print(f"wrote {out / 'model_selection_symmetry.csv'}")
    return v


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="docs/figures")
    ap.add_argument(
        "--part",
        choices=("all", "laws", "symmetry"),
        default="all",
        help="laws: parts 1-2 (J2, plane strain); symmetry: part 3",
    )
    args = ap.parse_args(argv)
    jaxform.enable_x64()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    values: dict[str, float] = {}
    if args.part in ("all", "symmetry"):
        values.update(symmetry_study(out))
        if args.part == "symmetry":
            return values

    # 1. J2 fit against Anand
    homog = ["mesh.nr=5", "mesh.nz=5", "mesh.element=q1q1"]
    anand = {}
    for f in SPEED_FACTORS:
        anand[f] = run(
            SEED, homog + [f"die.speed_mm_s={SEED_SPEED_MM_S * f!r}", f"time.dt_s={1.0 / f!r}"]
        )
    strain, stress = flow_curve(*anand[1.0])
    sy, hm = fit_j2(strain, stress)
    j2_path = out / "model_selection_j2_fit.toml"
    write_j2(j2_path, sy, hm)
    values.update(j2_sigma_y0_MPa=sy, j2_H_MPa=hm)
    print(
        f"J2 fit: sigma_y0 = {sy:.3f} MPa, H = {hm:.3f} MPa "
        f"(Anand flow stress {stress[0]:.2f} -> {stress[-1]:.2f} MPa)"
    )
    for f in SPEED_FACTORS:
        sc_a, res_a = anand[f]
        _, res_j = run(
            SEED,
            homog
            + [
                f"material.preset={str(j2_path)}",
                f"die.speed_mm_s={SEED_SPEED_MM_S * f!r}",
                f"time.dt_s={1.0 / f!r}",
            ],
        )
        strokes = res_a.history["stroke_mm"][4::4]
        err = rel_l2(force_on_strokes(res_j, strokes), force_on_strokes(res_a, strokes))
        values[f"j2_force_error_speed_x{f:g}"] = err
        values[f"anand_final_force_N_speed_x{f:g}"] = float(res_a.history["force_N"][-1])
        values[f"j2_final_force_N_speed_x{f:g}"] = float(res_j.history["force_N"][-1])
        print(
            f"speed x {f:g}: Anand final force {res_a.history['force_N'][-1]:.1f} N, J2 "
            f"{res_j.history['force_N'][-1]:.1f} N, force error (rel. L2) {err:.2%}"
        )

    # 2. plane strain against axisymmetry
    for name, config, over in (
        ("frictionless", SEED, homog),
        ("coulomb", FRICTION, ["mesh.nr=10", "mesh.nz=10", "time.dt_s=0.5"]),
    ):
        for geometry in ("axisymmetric", "plane_strain"):
            sc, res = (
                anand[1.0]
                if (name, geometry) == ("frictionless", "axisymmetric")
                else run(config, over + [f"mesh.geometry={geometry}"])
            )
            p = mean_pressure(sc, res)
            values[f"mean_pressure_MPa_{name}_{geometry}"] = p
            print(f"{name:12s} {geometry:13s}: mean die pressure {p:.2f} MPa at the end")
    for g in ("axisymmetric", "plane_strain"):
        values[f"friction_factor_{g}"] = (
            values[f"mean_pressure_MPa_coulomb_{g}"] / values[f"mean_pressure_MPa_frictionless_{g}"]
        )
    values["plane_strain_over_axisymmetric_frictionless"] = (
        values["mean_pressure_MPa_frictionless_plane_strain"]
        / values["mean_pressure_MPa_frictionless_axisymmetric"]
    )
    for k in (
        "friction_factor_axisymmetric",
        "friction_factor_plane_strain",
        "plane_strain_over_axisymmetric_frictionless",
    ):
        print(f"{k}: {values[k]:.4f}")
    with open(out / "model_selection.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["quantity", "value"])
        for k, v in values.items():
            w.writerow([k, f"{v:.6g}"])
    print(f"wrote {out / 'model_selection.csv'} and {j2_path}")
    return values


if __name__ == "__main__":
    main()
