"""Designing a two-blow forging with exact gradients: a tutorial.

    python examples/process_design.py            # 8 L-BFGS iterations (minutes)
    python examples/process_design.py --quick    # 2 iterations (what the tests run)

The job of a forging designer in miniature: a billet is preformed by a first blow, then
forged in a closed die with a flash land and trimmed.  How must the first blow's die be
shaped, and how much billet is needed, so that the second blow fills its cavity with the
least flash and the first blow stays within its press?  The first die's face is a spline
(its heights between r = 0 and 2.5 mm are two free control heights; the ends pinned),
the billet's volume a factor; jaxform differentiates the whole process (both blows, the
transfer of the part between them, the trim) with respect to both and L-BFGS-B moves them.

The scene is small on purpose (the seed's Al 1100-O billet at 673 K, a 3 x 3 mesh, 3 and 2
steps) so that every compiled program is small; a production scene is the same config
with finer meshes, remeshing and heat (configs/two_stage_disk.toml, docs/processes.md).
"""

import csv
import sys
import tempfile
from pathlib import Path

import numpy as np

import jaxform

jaxform.enable_x64()  # jaxform computes in float64; call this first

QUICK = "--quick" in sys.argv
SEED = Path(__file__).resolve().parents[1] / "configs" / "upsetting_seed.toml"
RADII = (0.0, 0.5, 1.0, 1.5, 2.5, 6.0)

# 1. The process: the seed's billet and material, two blows, a trim.  A config file would
#    hold the same tables ([[process.operation]]); a dict is handy in a script.
process = {
    "billet": {"diameter_mm": 5.0, "height_mm": 7.5},  # the upper half is modelled
    "mesh": {"nr": 3, "nz": 3, "element": "q1q1"},
    "material": {"preset": "al1100_673K"},
    "die": {"speed_mm_s": 0.075, "reduction": 0.1},  # the base scene's (each blow has its own)
    "friction": {"model": "shear", "m": 0.3},
    "time": {"dt_s": 2.5},
    "output": {"fields": False, "plots": False},
    "process": {
        "operation": [
            # the preform blow: a flat die sampled at RADII (the design bends it), 0.3 mm
            # above the billet's top at the start (within the design's +-0.3 mm it starts
            # clear of the part), closing to z = 3.375 mm
            {"kind": "forming", "name": "preform", "travel_mm": 0.675, "die": {
                "profile_mm": [[r, 4.05] for r in RADII]}},
            # the closed die: a shallow cone whose cavity ends at r = 2.6 mm, a flash land
            {"kind": "forming", "name": "finisher", "travel_mm": 0.3, "die": {
                "profile_mm": [[r, 3.38 + 0.05 * r] for r in RADII], "speed_mm_s": 0.15,
                "closed": True, "part_radius_mm": 2.6}},
            {"kind": "trim", "name": "trim", "radius_mm": 2.6},
        ]
    },
}  # fmt: skip


# 2. Run it forward once: the finisher's fill of its cavity, its flash, each blow's force
def blows(result) -> dict:
    """{operation name: its own history} of a process's forming operations."""
    return {run.operation.name: run.result.history for run in result.runs
            if run.operation.forming}  # fmt: skip


naive = blows(jaxform.run(process))
for name, h in naive.items():
    print(f"{name}: peak force {np.max(h['force_N']):.1f} N")
fin = naive["finisher"]
print(f"finisher: fill {fin['die_fill'][-1]:.5f}, flash {fin['flash_volume_mm3'][-1]:.4f} mm^3")

# 3. The design problem, as a [design] table: the variables, the objective and its weights
process["design"] = {
    "variables": ["billet_volume"],  # the billet's volume at its aspect
    "operation_variables": ["preform.die_spline"],  # the preform die's face
    "die_spline_controls": 2,
    "die_spline_r1_mm": 2.5,
    "die_spline_offset_max_mm": 0.3,
    "die_draft_deg": 30.0,  # manufacturability: the spline's slope and curvature
    "die_fillet_radius_min_mm": 5.0,
    "objective": "weighted_sum",
    "objective_operation": "finisher",
    "terms": ["die_fill", "flash_volume"],  # underfill (1 - fill) and flash (mm^3)
    "operation_terms": ["preform.press_capacity"],  # the preform press: 300 N
    # 1000 per unit of underfill (the cavity holds 134 mm^3 at the end, both halves: 7.5
    # per mm^3 missing) against 1 per mm^3 of flash: the least objective fills it
    "term_weights": [1000.0, 1.0, 1.0],
    "press_capacity_N": 300.0,
    "iterations": 2 if QUICK else 8,
}

# 4. Design: one forward run fixes the steps and meshes, then each iteration evaluates the
#    objective and its exact gradient through both blows and the trim
out = Path(tempfile.mkdtemp(prefix="process_design_"))
problem, hist = jaxform.run_design(
    process,
    out_dir=out,
    progress=lambda it, val, g, _: print(f"iteration {it}: objective {val:.6g}, |grad| {g:.3g}"),
    announce=print,
)
with open(out / "design_report.csv", newline="") as fh:
    report = {row["quantity"]: row for row in csv.DictReader(fh)}
print(f"{'':28s}{'start':>12s}{'designed':>12s}")
for q in ("objective", "die_fill", "flash_volume", "preform.peak_force_N", "finisher.peak_force_N"):
    print(f"{q:28s}{float(report[q]['start']):12.5g}{float(report[q]['best']):12.5g}")
print("design:", {k: round(v, 5) for k, v in problem.physical(hist.designs[hist.best]).items()})

# 5. The designed process is a config like any other: designed.toml (the die's designed
#    points, the billet's size) runs with `jaxform run` and gives the design's numbers
designed = blows(jaxform.run(out / "designed.toml"))
flash = designed["finisher"]["flash_volume_mm3"][-1]
best_flash = float(report["flash_volume"]["best"])
print(f"designed.toml: flash {flash:.6f} mm^3 (the design's {best_flash:.6f})")
print(f"files: {', '.join(sorted(p.name for p in out.iterdir()))}")
