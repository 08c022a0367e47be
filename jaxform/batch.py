"""Batched designs: many runs of one scene as ONE compiled program, sharded over devices.

    problem = build_problem(scene, groups=("friction",), objective=ForgingWork())
    designs = stack_designs([{"friction": jnp.array([mu])} for mu in mus])   # leading axis B
    batch = BatchProblem(problem)                     # or BatchProblem(problem, batch_mesh())
    J, traj = batch.value(designs)                    # J: (B,), traj fields: (B, ...)
    J, grads, traj = batch.value_and_grad(designs)    # per-sample gradients, grads[g]: (B, ...)

How.  A design problem (:mod:`jaxform.design.problem`) maps a design pytree to a
differentiable run over its fixed step schedule (:func:`jaxform.gradients.trajectory`);
here that map, and its ``jax.value_and_grad``, are ``jax.vmap``-ed over a leading batch axis
of the design and compiled once.  Per-sample gradients come for free: vmap of
value_and_grad.  The batch is sharded with ``jax.shard_map`` over a 1-D device mesh (axis
``"batch"``, :func:`batch_mesh`): each device runs its slice one design after another (a
vmapped slice deadlocked the CPU thread pool, :func:`_lanes`), the same code on host CPU
devices, GPUs or several hosts.  A batch whose size is not a
multiple of the device count is padded with copies of its last design and trimmed.

Under vmap every Newton loop runs until its slowest lane has converged (the others are
masked), so a batch costs the sum over steps of the *largest* iteration count in the
batch; designs of similar difficulty batch best.  Both linear backends batch: dense LU as a
batched LU, klujax's ``solve`` primitive has a vmap rule (one KLU factorization per lane).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from jaxform.design.problem import DesignProblem
from jaxform.gradients import GradientRunError
from jaxform.status import CAUSES, OK
from jaxform.xla_options import jit

AXIS = "batch"


def batch_mesh(devices=None) -> Mesh:
    """A 1-D mesh (axis ``"batch"``) over ``devices`` (default: all of ``jax.devices()``)."""
    devs = jax.devices() if devices is None else list(devices)
    return Mesh(np.asarray(devs), (AXIS,))


def stack_designs(designs) -> dict:
    """A list of design pytrees -> one pytree with a leading batch axis."""
    return jax.tree_util.tree_map(lambda *a: jnp.stack([jnp.asarray(v) for v in a]), *designs)


def batch_size(designs) -> int:
    return int(jax.tree_util.tree_leaves(designs)[0].shape[0])


@dataclass(frozen=True, eq=False)
class BatchProblem:
    """A design problem evaluated on a batch of designs at once (compiled once per
    problem, mesh and batch size)."""

    problem: DesignProblem
    mesh: Mesh | None = None  # 1-D device mesh for sharding; None: the default device

    def _program(self, fn):
        """fn(design, idx) vmapped over the designs (the scene's pattern ``idx`` shared,
        an argument rather than a constant of the program), or, sharded over the mesh,
        mapped one design after another on each device (see :func:`_lanes`)."""
        if self.mesh is None:
            return jit(jax.vmap(fn, in_axes=(0, None)))
        batched = _lanes(fn)
        spec = PartitionSpec(AXIS)
        # check_vma=False: the lanes are independent and the Newton/scan carries start from
        # replicated constants, which the varying-manual-axes check would reject
        return jit(
            jax.shard_map(
                batched,
                mesh=self.mesh,
                in_specs=(spec, PartitionSpec()),
                out_specs=spec,
                check_vma=False,
            )
        )

    @cached_property
    def _value(self):
        return self._program(self.problem._j)

    @cached_property
    def _value_and_grad(self):
        vg = jax.value_and_grad(self.problem._j, has_aux=True)

        def fn(d, idx):
            (val, traj), grad = vg(d, idx)
            return val, grad, traj

        return self._program(fn)

    def _place(self, designs):
        """Pad to a multiple of the device count and lay the batch axis over the mesh."""
        n = batch_size(designs)
        if self.mesh is None:
            return designs, n
        k = self.mesh.size
        pad = (-n) % k
        if pad:
            designs = jax.tree_util.tree_map(
                lambda a: jnp.concatenate([a, jnp.repeat(a[-1:], pad, axis=0)]), designs
            )
        sharding = NamedSharding(self.mesh, PartitionSpec(AXIS))
        return jax.device_put(designs, sharding), n

    def value(self, designs):
        """(J (B,), trajectories with a leading batch axis). Raises GradientRunError
        naming the first design whose run failed."""
        val, traj = self.value_per_design(designs)
        check_batch(traj)
        return val, traj

    def value_per_design(self, designs):
        """:meth:`value` without raising: a design whose run failed has a step status
        other than OK in its lane of ``traj.codes`` (the others stand), for callers that
        keep every other design's result (jaxform study)."""
        placed, n = self._place(designs)
        return _trim(self._value(placed, self.problem.scene.idx), n)

    def value_and_grad(self, designs):
        """(J (B,), dJ/d design with a leading batch axis, trajectories)."""
        placed, n = self._place(designs)
        val, grad, traj = _trim(self._value_and_grad(placed, self.problem.scene.idx), n)
        check_batch(traj)
        return val, grad, traj


def _lanes(fn):
    """fn(design, idx) over a device's slice of the batch, one design after another
    (``lax.map``), not vmapped.

    Why: vmapped, the dense solver's LU becomes LAPACK's batched getrf, which splits its
    batch over the CPU client's intra-op thread pool and waits for the parts.  With two
    host devices each running its slice on a thread of that pool, on a 2-core machine both
    threads wait for parts that no free thread can run: 16 designs on 2 host devices hung
    with both threads in ``jax::ParallelBatchMap`` (gdb, jaxlib 0.10.2).  One design at a
    time has no batched LU; the devices still run their slices in parallel, and on one CPU
    device the vmapped batch bought no throughput anyway (docs: benchmarks)."""

    def per_device(designs, idx):
        return jax.lax.map(lambda d: fn(d, idx), designs)

    return per_device


def _trim(tree, n: int):
    return jax.tree_util.tree_map(lambda a: a[:n], tree)


def check_batch(traj) -> None:
    """Raise :class:`GradientRunError` if a step of any run of the batch failed."""
    codes = np.asarray(traj.codes)
    bad = np.argwhere(codes != OK)
    if bad.size:
        b, k = (int(v) for v in bad[0])
        t = float(np.asarray(traj.time_s)[b, k + 1])
        raise GradientRunError(
            f"batched run: design {b}, step {k + 1} (to t = {t:g} s) failed: "
            f"{CAUSES.get(int(codes[b, k]), 'unknown')}; use a smaller time.dt_s or a finer "
            f"step schedule"
        )
