"""The batched-design test case, shared by tests/test_batch.py and its sharded subprocess.

A small elastic billet (3 x 3 q4, isotropic hypoelasticity with aluminium-like moduli,
Coulomb friction, 10 % upset in 10 steps, no line search): cheap to compile, with friction
and contact active, so that the design variable (the friction coefficient) matters.

    python tests/batch_case.py OUT.npz     # sharded batch (forward) over every device -> OUT.npz
"""

import sys
import tempfile
from pathlib import Path

import jax.numpy as jnp
import numpy as np

MUS = (0.05, 0.1, 0.2, 0.4)
SHARDED_MUS = MUS[:3] + tuple(np.linspace(0.06, 0.45, 12))
MATERIAL = """law = "elastic"
description = "isotropic hypoelasticity, aluminium-like moduli (batched-design test)"
[params]
G_MPa = 26000.0
K_MPa = 68000.0
"""


def problem():
    from jaxform.config import load_config
    from jaxform.design import build_problem
    from jaxform.design.objectives import ForgingWork
    from jaxform.scenes import build_scene

    path = Path(tempfile.mkdtemp()) / "elastic_test.toml"
    path.write_text(MATERIAL)
    cfg = load_config(
        {
            "billet": {"diameter_mm": 5.0, "height_mm": 7.5},
            "mesh": {"nr": 3, "nz": 3, "element": "q4"},
            "material": {"preset": str(path)},
            "die": {"speed_mm_s": 0.075, "reduction": 0.1},
            "friction": {"model": "coulomb", "mu": 0.3},
            "time": {"dt_s": 1.0},
            "solver": {"line_search": False},
            "output": {"fields": False, "plots": False},
        }
    )
    sc = build_scene(cfg)
    return build_problem(sc, groups=("friction",), objective=ForgingWork(), times=sc.step_targets())


def designs(mus=MUS):
    from jaxform.batch import stack_designs

    return stack_designs([{"friction": jnp.array([m])} for m in mus])


def sharded_main(out: str) -> None:
    import jax

    import jaxform
    from jaxform.batch import BatchProblem, batch_mesh

    jaxform.enable_x64()
    mesh = batch_mesh()
    batch = BatchProblem(problem(), mesh)
    # 15 designs on 2 devices: padded to 16, trimmed back; 8 a device is what hung when the
    # slices were vmapped (the batched LU waited on the thread pool both devices held)
    d = designs(SHARDED_MUS)
    placed, _ = batch._place(d)
    val, traj = batch.value(d)  # the forward program: half the compile time of the gradient
    np.savez(
        out,
        devices=len(jax.devices()),
        placed_devices=len(placed["friction"].sharding.device_set),
        value=np.asarray(val),
        force=np.asarray(traj.force_N),
        x=np.asarray(traj.x),
    )


if __name__ == "__main__":
    sharded_main(sys.argv[1])
