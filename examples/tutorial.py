"""jaxform from Python: run a scene, change a parameter, take a gradient.

    python examples/tutorial.py

The seed scene (configs/upsetting_seed.toml: an Al 1100-O billet upset between flat dies
at 673 K) on a coarse mesh and a short stroke, so that it runs in about a minute.
"""

from pathlib import Path

import numpy as np

import jaxform

jaxform.enable_x64()  # jaxform computes in float64; call this first

SEED = Path(__file__).resolve().parents[1] / "configs" / "upsetting_seed.toml"
# 3 x 3 elements, 10 % height reduction in 4 steps of 2.5 s (the seed: 10 x 10, 56.3 %)
SMALL = [
    "mesh.nr=3",
    "mesh.nz=3",
    "die.reduction=0.1",
    "time.dt_s=2.5",
    "output.fields=false",
    "output.plots=false",
]

# 1. run: config + overrides -> history (one row per step) and fields
slow = jaxform.run(SEED, SMALL)
print("stroke [mm]:", np.round(slow.history["stroke_mm"], 4))
print("force  [N]: ", np.round(slow.history["force_N"], 2))

# 2. change a parameter: twice the ram speed (Anand's law is rate sensitive)
fast = jaxform.run(SEED, SMALL + ["die.speed_mm_s=0.15"])
print(
    f"final force at 0.075 mm/s: {slow.history['force_N'][-1]:.2f} N, "
    f"at 0.15 mm/s: {fast.history['force_N'][-1]:.2f} N"
)

# 3. a gradient: forging work (N mm) with respect to the log of three material parameters,
# over the scene's own steps (they needed no cutback above) in one compiled program
scene = jaxform.build_scene(jaxform.load_config(SEED, SMALL))
problem = jaxform.build_problem(
    scene, groups=("material",), times=scene.step_targets(), single_program=True
)
work, grad, _ = problem.value_and_grad(problem.start)
for name, g in zip(problem.groups[0].names, np.asarray(grad["material"])):
    print(f"d work / d log {name} = {g:.4f} N mm")
print(f"forging work = {float(work):.4f} N mm")
