"""The figures of docs/outputs.md: damage, die wear and flow lines of the barrelled
upsetting scene (configs/upsetting_friction.toml), and die wear of frictionless upsetting
against its closed form.

    python experiments/forming_outputs.py [--mesh 8 8] [--reduction 0.35] [--dt 2.0]
                                          [--out docs/figures]

Writes outputs_damage.png, outputs_damage.csv (history: stroke, damage maxima and where),
outputs_flow_lines.png, outputs_flow_lines.csv (the lines' points at the end),
outputs_wear.png and outputs_wear.csv (the top die's wear on the frictional scene and
on the frictionless one with the closed form: sum over steps of K p rho (1 - R_n / R_n+1)
/ H, p and R from the material point, docs/outputs.md).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax.numpy as jnp
import numpy as np

import jaxform
from jaxform import plot
from jaxform.flowlines import flow_lines, straightness
from jaxform.forming_outputs import wear_profiles
from jaxform.io import write_csv
from jaxform.materialpoint import Ram, uniaxial_compression
from jaxform.postprocess import positions

K, H = 1e-3, 2000.0


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--mesh", type=int, nargs=2, default=[8, 8])
    ap.add_argument("--reduction", type=float, default=0.35)
    ap.add_argument("--dt", type=float, default=2.0)
    ap.add_argument("--spacing", type=float, default=0.5)
    ap.add_argument("--out", default="docs/figures")
    args = ap.parse_args()
    jaxform.enable_x64()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    common = [f"mesh.nr={args.mesh[0]}", f"mesh.nz={args.mesh[1]}", f"time.dt_s={args.dt}",
              f"die.reduction={args.reduction}", "output.fields=false", "output.plots=false",
              "wear.on=true", f"wear.k={K}", f"wear.hardness_MPa={H}"]  # fmt: skip
    fric = jaxform.run("configs/upsetting_friction.toml", common)
    seed = jaxform.run("configs/upsetting_seed.toml", common)
    h = fric.history
    scene = fric.final_scene
    pos = positions(scene, fric.fields["x"][-1])
    el = np.asarray(scene.mesh.elements)
    red = 100.0 * h["stroke_mm"][-1] / 7.5
    keys = [k for k in h if k.startswith("damage_")]
    write_csv(out / "outputs_damage.csv", {"stroke_mm": h["stroke_mm"], **{k: h[k] for k in keys}})
    fig = plot.cell_contours(
        pos,
        el,
        np.asarray(fric.fields["damage"][-1])[..., 0].max(axis=1),
        out / "outputs_damage.png",
        f"C-L damage, Coulomb 0.3, {red:.0f} %",
        "damage C-L [-]",
    )
    fig.axes[0].plot([h["damage_cl_r_mm"][-1]], [h["damage_cl_z_mm"][-1]], "rx", ms=10, mew=2)
    fig.savefig(out / "outputs_damage.png", dpi=120)
    lines = flow_lines(fric, args.spacing)
    title = f"flow lines ({args.spacing:g} mm apart), Coulomb 0.3, {red:.0f} %"
    plot.flow_lines(pos, el, lines.polylines(-1), out / "outputs_flow_lines.png", title)
    last = lines.points[-1]
    write_csv(out / "outputs_flow_lines.csv",
              {"line": lines.line, "r_mm": last[:, 0], "z_mm": last[:, 1]})  # fmt: skip
    # wear: frictional scene, frictionless scene and its closed form
    wf = wear_profiles(fric.final_scene, fric.final_state.wear_mm)["top"]
    ws = wear_profiles(seed.final_scene, seed.final_state.wear_mm)["top"]
    hs = seed.history
    sc = seed.scene
    t = jnp.asarray(hs["time_s"][1:])
    mp = uniaxial_compression(sc.model.law, sc.inputs.params, final_strain=1.0, n_steps=1,
                              ram=Ram(0.075, 7.5), times_s=t)  # fmt: skip
    p, radius = np.asarray(mp["stress_MPa"]), 2.5 * np.asarray(mp["lateral_stretch"])
    rho = ws["r_mm"]
    ref = np.zeros_like(rho)
    for n in range(len(p) - 1):
        on = rho <= radius[n + 1] * (1.0 + 1e-12)
        ref += np.where(on, K * p[n + 1] * rho * (1.0 - radius[n] / radius[n + 1]) / H, 0.0)
    write_csv(out / "outputs_wear.csv", {"r_mm": rho, "wear_coulomb_mm": wf["wear_mm"],
                                         "wear_frictionless_mm": ws["wear_mm"],
                                         "closed_form_mm": ref})  # fmt: skip
    fig, ax = plot._figure(figsize=(6.5, 4))
    ax.plot(rho, 1e3 * wf["wear_mm"], "-", label="Coulomb 0.3")
    ax.plot(rho, 1e3 * ws["wear_mm"], "-", label="frictionless")
    ax.plot(rho[::4], 1e3 * ref[::4], "o", mfc="none", label="frictionless, closed form")
    ax.set_xlabel("r on the top die [mm]")
    ax.set_ylabel("wear depth [µm]")
    ax.set_xlim(0.0, 1.2 * radius[-1])
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(f"Archard wear, K = {K:g}, H = {H:g} MPa, {red:.0f} % reduction")
    plot._save(fig, out / "outputs_wear.png")
    inside = ref > 0
    err = np.max(np.abs(ws["wear_mm"][inside] / ref[inside] - 1.0))
    # 2026-11-26 (defaults): C-L max 0.1466 at r = 2.557, z = 2.075 mm (the die-edge
    # element); frictionless wear against the closed form 2.7e-11; largest bow 0.269 mm
    at = f"r = {h['damage_cl_r_mm'][-1]:.3f}, z = {h['damage_cl_z_mm'][-1]:.3f} mm"
    print(f"damage C-L max {h['damage_cl_max'][-1]:.4g} at {at} (r_max {pos[:, 0].max():.3f} mm)")
    print(f"frictionless wear against the closed form: max relative error {err:.2e}")
    print(f"flow lines of the frictional run: largest bow {straightness(lines):.3f} mm")


if __name__ == "__main__":
    main()
