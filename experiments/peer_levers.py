"""Two levers of the peer punch's solve time, measured on jaxform's side alone.

    python experiments/peer_levers.py [--mesh 100] [--refresh A:R:D ...] [--chunks 512 0 ...]

* ``--refresh``: modified Newton's refresh rule, each ``ACCEPT:REFRESH:DEPTH``
  (:class:`jaxform.solver.ModifiedNewton`'s ``accept_ratio``, ``refresh_ratio`` ('none':
  its default by depth) and ``anderson_depth``), each run in its own process: the solve
  after compilation (as ``bench_peer.py`` times it), Newton iterations and assemblies.
* ``--chunks``: the element Jacobians of the final state in chunks of that many elements
  (``ElementTerm.jacobian_chunk``; 0: one vmap), best of 5, beside the residual pass;
  then with the 3 x 3 strain increment of the code before 2026-12-07 in place of the
  planar one (``kinematics.strain_increment_planar``); then (a probe, wrong derivatives)
  with the material point's JVP replaced by one that computes the point's values but
  maps the tangent df straight to the stress: what the element Jacobians cost without
  the point's own 5-component jacfwd.

The punch is ``bench_peer.py``'s (q4, ``solver.newton = 'auto'``, ``solver.linear =
'auto'``).  Timings are noisy on a shared machine: compare rows of one run.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))


def _refresh_child(n: int, spec: str) -> dict:
    import bench_peer

    import jaxform.capacity
    import jaxform.scenes
    import jaxform.solver as solver

    accept, refresh, depth = spec.split(":")
    plain = solver.newton_variant

    def variant(*args, **kwargs):
        v = plain(*args, **kwargs)
        if isinstance(v, solver.ModifiedNewton):
            v = dataclasses.replace(
                v,
                accept_ratio=float(accept),
                refresh_ratio=None if refresh == "none" else float(refresh),
                anderson_depth=int(depth),
            )
        return v

    # the scene builders bind the name at import
    jaxform.scenes.newton_variant = variant
    jaxform.capacity.newton_variant = variant
    r = bench_peer.run_jaxform(n, "q4", split=False)
    keys = ("solve_s", "newton_iterations", "assemblies")
    return {"refresh": spec, **{k: r[k] for k in keys}, "force_N": r["force_N"][-1]}


def _chunks(n: int, chunks: list[int]) -> list[dict]:
    import bench_peer
    import jax
    from timing import best_of

    import jaxform
    from jaxform.config import load_config
    from jaxform.scenes import build_scene
    from jaxform.simulation import simulate
    from jaxform.stepping import step_context

    jaxform.enable_x64()
    scene = build_scene(load_config(bench_peer.jaxform_config(n, "q4")))
    st = simulate(scene).final_state
    model = scene.model
    ctx = step_context(model, st, scene.inputs, scene.idx, st.t, jax.numpy.asarray(scene.dt))

    def timed(term, chunk):
        def jacobians(x, ctx):
            ep = term.residual_pass(x, ctx, model.layout)
            return term.jacobians(term.element_fn(ctx, model.layout), ep, ctx.gauss)

        def residual(x, ctx):
            return term.residual_pass(x, ctx, model.layout).r_e

        jac, res = jax.jit(jacobians), jax.jit(residual)
        return dict(
            chunk=chunk,
            jacobians_ms=1e3 * best_of(lambda: jac(st.x, ctx), 5),
            residual_pass_ms=1e3 * best_of(lambda: res(st.x, ctx), 5),
        )

    rows = [timed(dataclasses.replace(model.element, jacobian_chunk=c), c) for c in chunks]
    import jaxform.kinematics as kinematics

    planar = kinematics.strain_increment_planar
    kinematics.strain_increment_planar = kinematics.strain_increment  # the code before
    rows.append(timed(model.element, "default, 3x3 strain increment"))
    kinematics.strain_increment_planar = planar
    _without_point_tangent()
    rows.append(timed(model.element, "default, no point jacfwd"))
    return rows


def _without_point_tangent():
    """Replace formulations.planar_point_update by one whose JVP takes df as the stress
    tangent (the values unchanged; programs traced after this call see it)."""
    from functools import partial

    import jax
    import jax.numpy as jnp

    import jaxform.formulations as formulations

    point = formulations._point

    @partial(jax.custom_jvp, nondiff_argnums=(0, 1))
    def update(law, alpha, f, state, params, dt, solution=None):
        return point(law, alpha, f, state, params, dt, solution)

    def rule(law, alpha, primals, tangents):
        out = point(law, alpha, *primals)
        stress, new, ok = jax.tree_util.tree_map(jnp.zeros_like, out)
        return out, (stress + tangents[0], new, ok)

    update.defjvp(rule)
    formulations.planar_point_update = update


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--mesh", type=int, default=100)
    ap.add_argument("--refresh", nargs="*", default=["0.5:none:3", "0.5:0.5:3", "0.5:0.15:3"])
    ap.add_argument("--chunks", type=int, nargs="*", default=[512, 0, 128, 2048])
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print("RESULT " + json.dumps(_refresh_child(args.mesh, args.child)), flush=True)
        return 0
    for spec in args.refresh:
        cmd = [sys.executable, __file__, "--mesh", str(args.mesh), "--child", spec]
        out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
        r = json.loads([s for s in out.splitlines() if s.startswith("RESULT ")][-1][7:])
        print(
            f"accept:refresh:depth {spec}: solve {r['solve_s']:.2f} s, "
            f"{r['newton_iterations']} iterations, {r['assemblies']} assemblies, "
            f"F = {r['force_N']:.6f} N/mm",
            flush=True,
        )
    if args.chunks:
        for r in _chunks(args.mesh, args.chunks):
            print(
                f"chunk {r['chunk']}: element Jacobians {r['jacobians_ms']:.1f} ms, "
                f"residual pass {r['residual_pass_ms']:.1f} ms",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
