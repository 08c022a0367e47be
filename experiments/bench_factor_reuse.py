"""What reusing the sparse LU across Newton iterations and load steps would buy (issue 7).

    python experiments/bench_factor_reuse.py [--mesh 100] [--accept 0.5] [--refresh 0.1]

A measurement, not a solver of the library: the seed scene (configs/upsetting_seed.toml,
q1q1, Anand, frictionless) advanced step by step from Python with the compiled pieces of
jaxform (``simulate._step_residual``, ``_step_residual_and_jacobian``, ``contact_step``,
``converged_state``) and klujax's split API outside jit: ``analyze`` once, ``factor`` only
when the Jacobian is refreshed, ``solve_with_numeric`` (the triangular solves alone) in
every other iteration.  The factorization objects live in Python and are freed when
replaced; inside a compiled program klujax's handles would never be freed, and
``refactor`` (in place, the old pivot order) raises on a zero pivot, which a contact
multiplier row has once its node comes into contact.

Modified Newton: an iteration solves with the last factorization J_old (of this step or an
earlier one).  Its full step is accepted when ||R|| falls to <= ``--accept`` x its value,
otherwise rejected (x unchanged) and the next iteration refreshes the Jacobian (assembly +
factorization) and takes an exact Newton step with backtracking.  A step accepted with a
contraction worse than ``--refresh`` also refreshes the next iteration.  Converged as in
jaxform: ||R|| <= rtol x force scale (1e-10).  Every step starts from the rate predictor.

Prints the run time after a first (compiling) run, the iterations, factorizations and
rejected steps, and the final force next to the compiled exact-Newton run's
(``experiments/bench_scale.py --full N`` times that one).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

SEED = "configs/upsetting_seed.toml"


def build(n: int):
    import jax
    import jax.numpy as jnp

    import jaxform
    from jaxform.config import load_config
    from jaxform.scenes import build_scene
    from jaxform.simulate import (_step_residual, _step_residual_and_jacobian, contact_step,
                                  converged_state, die_force)

    jaxform.enable_x64()
    cfg = load_config(SEED, [f"mesh.nr={n}", f"mesh.nz={n}", "output.fields=false",
                             "output.plots=false"])
    sc = build_scene(cfg)
    model, idx, inp = sc.model, sc.idx, sc.inputs
    fns = dict(
        residual=jax.jit(lambda x, args: _step_residual(model, x, args)),
        residual_and_jacobian=jax.jit(lambda x, args: _step_residual_and_jacobian(model, x, args)),
        contact_step=jax.jit(lambda st: contact_step(model, st, inp, idx)),
        converged=jax.jit(lambda st, x, g, t, cs: converged_state(model, st, x, g, t, inp, cs,
                                                                  idx)),
        force=jax.jit(lambda x, t: die_force(model, x, inp, t, idx)),
        rows=jnp.asarray(idx.rows, jnp.int32), cols=jnp.asarray(idx.cols, jnp.int32),
    )
    return sc, fns


def run(sc, fns, accept: float, refresh_above: float, max_iterations: int = 100) -> dict:
    import jax.numpy as jnp
    import klujax

    inp, idx = sc.inputs, sc.idx
    rows, cols = fns["rows"], fns["cols"]
    symbolic = klujax.analyze(rows, cols, sc.model.layout.n_dofs)
    rtol = sc.newton.rtol
    st = sc.initial_state()
    numeric, refresh = None, True
    counts = dict(iterations=0, factorizations=0, rejected=0)
    per_step = []
    t0 = time.perf_counter()
    for k, t_new in enumerate(sc.step_targets()):
        dt = float(t_new) - float(st.t)
        cstep = fns["contact_step"](st)
        args = (st.gauss, inp.coords, jnp.asarray(t_new), jnp.asarray(dt), inp.params, inp.die,
                inp.c_contact, cstep, idx, None)
        x = st.x + dt * st.x_rate
        r, g, code, scale = fns["residual"](x, args)
        its = 0
        while float(jnp.linalg.norm(r)) > rtol * float(scale):
            its += 1
            if its > max_iterations:
                raise RuntimeError(f"step {k + 1}: no convergence in {max_iterations} iterations")
            fresh = numeric is None or refresh
            if fresh:
                r, vals, g, code, scale = fns["residual_and_jacobian"](x, args)
                numeric = klujax.factor(rows, cols, vals, symbolic)  # the old one is freed
                counts["factorizations"] += 1
                refresh = False
            dx = klujax.solve_with_numeric(numeric, -r, symbolic)
            rn = float(jnp.linalg.norm(r))
            alpha = 1.0
            for _ in range(10 if fresh else 1):  # backtracking only for exact Newton steps
                xt = x + alpha * dx
                rt, gt, code_t, scale_t = fns["residual"](xt, args)
                if int(code_t) == 0 and float(jnp.linalg.norm(rt)) <= (1 - 1e-4 * alpha) * rn:
                    break
                alpha *= 0.5
            ratio = float(jnp.linalg.norm(rt)) / rn
            if not fresh and (int(code_t) != 0 or ratio > accept):
                refresh = True  # a stale step that does not contract: refresh, same x
                counts["rejected"] += 1
                continue
            if ratio > refresh_above:
                refresh = True
            x, r, g, scale = xt, rt, gt, scale_t
        counts["iterations"] += its
        per_step.append(its)
        st = fns["converged"](st, x, g, jnp.asarray(t_new), cstep)
    force = float(fns["force"](st.x, st.t))
    return dict(seconds=time.perf_counter() - t0, force_N=force, per_step=per_step, **counts)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--mesh", type=int, default=100)
    ap.add_argument("--accept", type=float, default=0.5,
                    help="largest residual ratio a step with the old factorization may have")
    ap.add_argument("--refresh", type=float, default=0.1,
                    help="a ratio above this refreshes the Jacobian for the next iteration")
    args = ap.parse_args()
    sc, fns = build(args.mesh)
    first = run(sc, fns, args.accept, args.refresh)  # compiles the pieces
    out = run(sc, fns, args.accept, args.refresh)
    steps = np.asarray(out["per_step"])
    print(f"seed {args.mesh}x{args.mesh}, {sc.model.layout.n_dofs} unknowns, {len(steps)} steps: "
          f"{out['seconds']:.1f} s after compile ({first['seconds']:.1f} s first run), "
          f"{out['iterations']} Newton iterations ({steps.mean():.2f}/step), "
          f"{out['factorizations']} factorizations, {out['rejected']} rejected steps, "
          f"final force {out['force_N']:.2f} N")


if __name__ == "__main__":
    main()
