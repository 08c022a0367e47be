"""Coupled thermal model: conduction against series solutions, and the hot upsetting scene
against its isothermal run.

    python experiments/thermal_verification.py [--out docs/figures] [--quick]

1. Conduction alone (tests/thermal_series.py: slab and infinite cylinder, Bi = 1, cooling
   by a Robin boundary from 673 K to 293 K up to Fo = 0.9) on 4, 8, 16 elements with
   dt ~ h^2: the largest nodal error in theta = (T - 293)/(673 - 293) at Fo = 0.23, 0.45,
   0.9, and its observed order.
2. configs/hot_upsetting.toml (dies at 473 K, shear friction 0.3) coupled and isothermal
   (thermal.model = none, the lumped al1100_673K preset): final force, peak force,
   temperatures, barrel (largest radius and radius at the top), the energy balance.
Writes thermal_conduction.csv (column cylinder: 0 the slab, 1 the cylinder) and
hot_upsetting.csv (column coupled: 1 coupled, 0 isothermal); --quick: 4 and 8 elements.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

import jaxform
from jaxform.config import load_config
from jaxform.io import write_csv
from jaxform.postprocess import HEAT_COLUMNS, nodal_temperature, positions
from jaxform.scenes import build_scene
from jaxform.simulation import simulate

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from thermal_series import cylinder_theta, slab_theta  # noqa: E402

ALPHA = 222.0 / (2710.0 * 904.0 * 1e-6)  # mm^2/s of the al1100 presets
CASES = {  # geometry, section (half width, half height) mm, cells(n), (h_die, h_air), series
    "slab": ("plane_strain", (0.5, 1.0), lambda n: (1, n), (222000.0, 0.0), 1,
             lambda x, fo: slab_theta(x, fo, 1.0)),
    "cylinder": ("axisymmetric", (1.0, 0.25), lambda n: (n, 1), (0.0, 222000.0), 0,
                 lambda r, fo: cylinder_theta(r, fo, 1.0)),
}  # fmt: skip


def conduction(case: str, n: int) -> tuple[float, float]:
    """(largest |theta error|, wall s) of one case on n elements, dt = 4e-4 (4/n)^2 s."""
    geometry, size, cells, (h_die, h_air), axis, ref = CASES[case]
    nr, nz = cells(n)
    cfg = load_config(
        {
            "billet": {"diameter_mm": 2 * size[0], "height_mm": 2 * size[1]},
            "mesh": {"element": "q1p0", "geometry": geometry, "nr": nr, "nz": nz},
            "die": {"speed_mm_s": 1e-6, "reduction": 5e-9},
            "thermal": {
                "model": "coupled",
                "air_temperature_K": 293.0,
                "die_temperature_K": 293.0,
                "emissivity": 0.0,
                "taylor_quinney": 0.0,
                "htc_die_W_m2K": h_die,
                "htc_air_W_m2K": h_air,
            },
            "time": {"dt_s": 4e-4 * (4 / n) ** 2},
            "output": {"fields": False, "plots": False},
        }  # fmt: skip
    )
    t0 = time.perf_counter()
    sc = build_scene(cfg)
    res = simulate(sc)
    wall = time.perf_counter() - t0
    times, err = res.history["time_s"], 0.0
    for k in (len(times) // 4, len(times) // 2, len(times) - 1):
        theta = (nodal_temperature(sc, res.fields["x"][k]) - 293.0) / 380.0
        coord = positions(sc, res.fields["x"][k])[:, axis]
        err = max(err, float(np.max(np.abs(theta - ref(coord, ALPHA * times[k])))))
    return err, wall


def hot_upsetting() -> dict:
    rows: list[dict] = []
    for label, over in (
        ("coupled", []),
        ("isothermal", ["thermal.model=none", "material.preset=al1100_673K"]),
    ):
        cfg = load_config("configs/hot_upsetting.toml", over)
        t0 = time.perf_counter()
        sc = build_scene(cfg)
        res = simulate(sc)
        wall = time.perf_counter() - t0
        h = res.history
        pos = positions(sc, res.fields["x"][-1])
        row = dict(
            run=label,
            final_force_N=h["force_N"][-1],
            peak_force_N=h["force_N"].max(),
            largest_radius_mm=pos[:, 0].max(),
            top_radius_mm=pos[sc.mesh.node_sets["top"], 0].max(),
            steps=len(h["time_s"]) - 1,
            newton_per_step=h["newton_iterations"][1:].mean(),
            wall_s=wall,
        )
        if "mean_temperature_K" in h:
            heat = {k: h[k][-1] for k in HEAT_COLUMNS}
            row.update(
                mean_temperature_K=h["mean_temperature_K"][-1],
                min_temperature_K=h["min_temperature_K"][-1],
                max_temperature_K=h["max_temperature_K"][-1],
                **heat,
                balance_mJ=heat["heat_stored_mJ"]
                - (heat["heat_plastic_mJ"] - heat["heat_to_dies_mJ"] - heat["heat_to_air_mJ"]),
            )
        rows.append(row)
        print(", ".join(f"{k} {v:.6g}" if not isinstance(v, str) else v for k, v in row.items()))
    keys = [k for k in rows[0] if k != "run"]  # the coupled row has every column
    return {k: [r.get(k, float("nan")) for r in rows] for k in keys}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="docs/figures")
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    jaxform.enable_x64()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    sizes = (4, 8) if args.quick else (4, 8, 16)
    rows = {"cylinder": [], "elements": [], "max_theta_error": [], "order": [], "wall_s": []}
    for case in CASES:
        errs = []
        for n in sizes:
            err, wall = conduction(case, n)
            order = np.log2(errs[-1] / err) if errs else float("nan")
            errs.append(err)
            for k, v in zip(rows, (float(case == "cylinder"), n, err, order, wall)):
                rows[k].append(v)
            print(f"{case} n={n}: theta error {err:.3e}, order {order:.2f}, {wall:.1f} s")
    write_csv(out / "thermal_conduction.csv", rows)  # cylinder: 0 the slab, 1 the cylinder
    if not args.quick:
        hot = hot_upsetting()
        write_csv(out / "hot_upsetting.csv", dict(coupled=[1, 0], **hot))


if __name__ == "__main__":
    main()
