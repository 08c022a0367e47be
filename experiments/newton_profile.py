"""Where a scene's Newton iterations go: per step and per phase, and inside chosen steps.

    python experiments/newton_profile.py configs/closed_die_flash.toml [--set k=v ...]
        [--replay 34 47] [--json out.json]

Runs the scene once (``jaxform.driver.run``, one step per compiled chunk, so that the
state before every step is captured) and prints:

* per step: time, step size, iterations (all attempts), cutbacks, remeshed, the number of
  iterations of the last attempt, its residual history's plateau (the smallest ratio
  ||R_k+1|| / ||R_k|| over its last iterations) and the wall time;
* by phase: before the flash (flash volume 0), in the flash, the first step on a new mesh
  (after a remesh), the steps that cut back; steps, iterations, iterations per step,
  iterations in failed attempts;
* with ``--replay ROW ...``: that step solved again from its captured state, in Python,
  iteration by iteration, as :func:`jaxform.stepping.attempt_step` does it (the attempts of
  halving size, each :func:`jaxform.solver.newton` with its line search): per iteration
  ||R|| / F, the line-search halvings taken, the step size alpha, the contact statuses that
  changed (open / stick / slip of the candidates, corner facets with a multiplier) and
  where the residual is largest (its block and the node's position).

One run, with full Newton (the flash scene's size); timings are wall times on whatever
else the machine is doing.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _capture_chunks():
    """Record the arguments of every compiled chunk (jaxform.chunks.chunk)."""
    import jaxform.chunks as chunks

    calls = []
    real = chunks.chunk

    def chunk(scene, stepper, state, control, inp, fac):
        calls.append(dict(scene=scene, stepper=stepper, state=state, control=control, inp=inp))
        return real(scene, stepper, state, control, inp, fac)

    chunks.chunk = chunk
    return calls


def phase_table(h: dict, iters_last: np.ndarray) -> list[dict]:
    """Iterations by phase (rows 1..): before the flash, in the flash, the first step on a
    new mesh, the steps that cut back (a step may be in several)."""
    n = len(h["time_s"])
    its = np.asarray(h["newton_iterations"], float)[1:]
    cb = np.asarray(h["cutbacks"], float)[1:]
    remeshed = np.asarray(h.get("remeshed", np.zeros(n)), float)
    after_remesh = np.zeros(n - 1, bool)
    after_remesh[:] = remeshed[:-1] > 0  # row k+1 is the first step on the mesh of row k's remesh
    flash = np.asarray(h.get("flash_volume_mm3", np.zeros(n)), float)[1:] > 0
    failed = its - iters_last  # iterations of the failed attempts of each step
    phases = {
        "all": np.ones(n - 1, bool),
        "before flash": ~flash,
        "in flash": flash,
        "first step on a new mesh": after_remesh,
        "other steps": ~after_remesh,
        "steps with a cutback": cb > 0,
    }
    rows = []
    for name, m in phases.items():
        rows.append(
            dict(
                phase=name,
                steps=int(m.sum()),
                iterations=int(its[m].sum()),
                per_step=float(its[m].mean()) if m.any() else 0.0,
                in_failed_attempts=int(failed[m].sum()),
                cutbacks=int(cb[m].sum()),
            )
        )
    return rows


def _plateau(hist: np.ndarray) -> float:
    """The worst contraction ||R_k+1|| / ||R_k|| over the finite history (1: stalls)."""
    h = hist[np.isfinite(hist)]
    if len(h) < 2:
        return 0.0
    return float(np.max(h[1:] / np.maximum(h[:-1], 1e-300)))


def replay(
    call: dict, verbose: bool = True, h: float | None = None, at_rest: bool = False
) -> list[dict]:
    """The captured step solved again in Python, attempt by attempt and iteration by
    iteration (see the module docstring); returns one record per iteration.  ``h``: the
    first attempt's step size (default: the run's); ``at_rest``: the first attempt starts
    from the state itself, not from the predictor (x + h x_rate)."""
    import jax
    import jax.numpy as jnp

    from jaxform.stepping import (
        StepLinear,
        _step_residual,
        _step_residual_and_jacobian,
        step_context,
    )

    scene, stepper, st, control, inp = (
        call[k] for k in ("scene", "stepper", "state", "control", "inp")
    )
    model, idx, s = stepper.model, scene.idx, stepper.newton
    lay = model.layout
    lin = StepLinear(lay.n_dofs, stepper.linear)
    report = jax.jit(lambda x, ctx: model.contact_report(x, ctx)[0])
    h = float(control.h) if h is None else h
    h_min = float(control.dt_max) * 0.5**stepper.max_cutbacks
    t0, t_end = float(st.t), float(control.t_end)
    snap = 1e-9 * float(control.dt_max)
    x_state = np.asarray(st.x)
    rate = np.asarray(st.x_rate)
    coords = np.asarray(inp.coords)
    records = []
    attempt = 0
    while True:
        t_new = t_end if t0 + h >= t_end - snap else t0 + h
        hh = t_new - t0
        ctx = step_context(model, st, inp, idx, jnp.asarray(t_new), jnp.asarray(hh))
        x = x_state + (hh * rate if attempt == 0 and not at_rest else 0.0)
        r, _, code, scale = _step_residual(model, jnp.asarray(x), ctx)
        if int(code) != 0:
            x = x_state
            r, _, code, scale = _step_residual(model, jnp.asarray(x), ctx)
        status = np.asarray(report(jnp.asarray(x), ctx))
        fmult = np.asarray(x)[np.asarray(idx.facet_mult)] if lay.n_facets else np.zeros(0)
        rn = float(jnp.linalg.norm(r))
        start = rn / max(float(scale), 1e-300)
        if verbose:
            print(
                f"  attempt {attempt}: dt {hh:.4g} s, start ||R||/F "
                f"{rn / max(float(scale), 1e-300):.3e}",
                flush=True,
            )
        conv = rn <= s.rtol * float(scale)
        k, codet = 0, code
        while not conv and k < s.max_iterations:
            r, vals, _, code_j, scale = _step_residual_and_jacobian(model, jnp.asarray(x), ctx)
            dx = np.asarray(lin(vals, -r, ctx, False))
            rnorm = float(jnp.linalg.norm(r))
            alpha, bt = 1.0, 0
            while True:
                xt = x + alpha * dx
                rt, _, codet, scalet = _step_residual(model, jnp.asarray(xt), ctx)
                bad = int(codet) != 0 or float(jnp.linalg.norm(rt)) > (1 - 1e-4 * alpha) * rnorm
                if not (bad and bt < s.max_backtracks):
                    break
                bt, alpha = bt + 1, 0.5 * alpha
            x = xt
            rtn = float(jnp.linalg.norm(rt))
            new_status = np.asarray(report(jnp.asarray(x), ctx))
            new_fmult = np.asarray(x)[np.asarray(idx.facet_mult)] if lay.n_facets else fmult
            changed = np.nonzero(new_status != status)[0]
            fchanged = int(np.sum((new_fmult > 0) != (fmult > 0)))
            rabs = np.abs(np.asarray(rt))
            j = int(np.argmax(rabs))
            block, where = _where(j, lay, idx, coords, x)
            rec = dict(
                step_t=t0,
                attempt=attempt,
                dt=hh,
                it=k + 1,
                start=start,
                res=rtn / float(scalet),
                contraction=rtn / max(rnorm, 1e-300),
                backtracks=bt,
                alpha=alpha,
                code=int(codet),
                status_changes=len(changed),
                facet_changes=fchanged,
                worst_block=block,
                worst_at=where,
                changed_at=[_cand_pos(c, lay, idx, coords, x) for c in changed[:4]],
            )
            records.append(rec)
            if verbose:
                print(
                    f"    it {k + 1:2d}: ||R||/F {rec['res']:.3e} (x{rec['contraction']:.2g}) "
                    f"backtracks {bt} status changes {len(changed):2d} facets {fchanged:2d} "
                    f"worst {block} at {where} changed at {rec['changed_at']}",
                    flush=True,
                )
            status, fmult = new_status, new_fmult
            conv = int(codet) == 0 and rtn <= s.rtol * float(scalet)
            k += 1
            if int(codet) != 0:
                break
        if verbose:
            print(f"  attempt {attempt}: {'converged' if conv else 'failed'} (code {int(codet)})")
        if conv:
            return records
        if h <= h_min * (1 + 1e-9):
            return records
        h, attempt = 0.5 * h, attempt + 1


def first_steps_table(calls: list[dict], h: dict) -> str:
    """Each first step on a new mesh replayed at the step size the run took (its last
    attempt's), from the predictor (x + h x_rate, as the run's mapped rates give it) and
    from the state at rest: iterations of the first attempt ('F': not converged within the
    solver's iterations, then halved as the run would) and its start ||R|| / F."""
    remeshed = np.asarray(h.get("remeshed", np.zeros(len(h["time_s"]))))
    lines = ["| row | t (s) | dt (s) | predictor: iterations, start | at rest: iterations, start |",
             "|---|---|---|---|---|"]  # fmt: skip
    totals = {False: 0, True: 0}
    for row in range(2, len(h["time_s"])):
        if remeshed[row - 1] == 0 or row > len(calls):
            continue
        cells = []
        for at_rest in (False, True):
            recs = replay(calls[row - 1], verbose=False, h=float(h["dt_s"][row]), at_rest=at_rest)
            first = [r for r in recs if r["attempt"] == 0]
            conv = len(first) == len(recs)  # no later attempt (none at all: it started converged)
            totals[at_rest] += len(recs)
            start = first[0]["start"] if first else 0.0
            cells.append(f"{len(first)}{'' if conv else 'F'}, {start:.2g}")
        lines.append(f"| {row} | {h['time_s'][row - 1]:.3f} | {h['dt_s'][row]:.4g} | "
                     f"{cells[0]} | {cells[1]} |")  # fmt: skip
    lines.append(f"iterations in all (with halvings): predictor {totals[False]}, "
                 f"at rest {totals[True]}")  # fmt: skip
    return "\n".join(lines)


def _cand_pos(c, lay, idx, coords, x):
    node = int(np.asarray(idx.contact_nodes)[c])
    p = coords[node] + lay.nodal(np.asarray(x))[node, :2]
    return (round(float(p[0]), 3), round(float(p[1]), 3))


def _where(j, lay, idx, coords, x):
    """The block of dof j and the position (mm) of its node."""
    x = np.asarray(x)
    if j < lay.n_node_dofs:
        node = j // lay.n_fields
        block = "node"
    elif j < lay.n_node_dofs + 2 * lay.n_contact:
        c = (j - lay.n_node_dofs) // 2
        node = int(np.asarray(idx.contact_nodes)[c])
        block = "contact_n" if (j - lay.n_node_dofs) % 2 == 0 else "contact_t"
    else:
        f = j - lay.n_node_dofs - 2 * lay.n_contact
        node = int(np.asarray(idx.facet_dofs)[f, 0]) // lay.n_fields
        block = "facet"
    p = coords[node] + lay.nodal(x)[node, :2]
    return block, (round(float(p[0]), 3), round(float(p[1]), 3))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("config")
    ap.add_argument("--set", action="append", default=[], dest="overrides")
    ap.add_argument("--replay", type=int, nargs="*", default=[], help="history rows")
    ap.add_argument(
        "--first-steps",
        action="store_true",
        help="replay each first step on a new mesh at the size the run took, from the "
        "predictor and from the state at rest",
    )
    ap.add_argument("--json", default=None, help="write the tables here")
    a = ap.parse_args(argv)
    import jax

    jax.config.update("jax_enable_x64", True)
    from jaxform.driver import run
    from jaxform.simulation import SimulationError

    calls = _capture_chunks()
    walls = []
    t_start = time.perf_counter()

    def progress(info):
        walls.append(time.perf_counter())

    overrides = ["solver.chunk_steps=1", "output.plots=false", *a.overrides]
    try:
        res = run(a.config, overrides, progress=progress)
    except SimulationError as err:
        res = err.result
        print("stopped:", err)
    total = time.perf_counter() - t_start
    h = res.history
    hists = np.asarray(res.newton_histories)
    last = np.array([np.sum(np.isfinite(r)) - 1 for r in hists])
    n = len(h["time_s"])
    print(
        f"{a.config}: {n - 1} steps, {int(np.sum(h['newton_iterations']))} iterations, "
        f"{np.mean(h['newton_iterations'][1:]):.2f} per step, {total:.1f} s in all "
        f"(incl. compile), end force {h['force_N'][-1]:.6g} N"
    )
    step_wall = np.diff(np.concatenate([[t_start], walls]))[: n - 1] if walls else np.zeros(n - 1)
    print(" row   t(s)    dt   its last cb rm  plateau   wall(s)  force(N)")
    remeshed = h.get("remeshed", np.zeros(n))
    for k in range(1, n):
        wall = step_wall[k - 1] if k - 1 < len(step_wall) else 0.0
        print(
            f"{k:4d} {h['time_s'][k]:7.3f} {h['dt_s'][k]:6.3f} "
            f"{int(h['newton_iterations'][k]):4d} {last[k - 1]:4d} {int(h['cutbacks'][k]):2d} "
            f"{int(remeshed[k]):2d} {_plateau(hists[k - 1]):8.3g} {wall:8.2f} "
            f"{h['force_N'][k]:9.2f}"
        )
    table = phase_table(h, last)
    print("| phase | steps | iterations | per step | in failed attempts | cutbacks |")
    print("|---|---|---|---|---|---|")
    for r in table:
        print(
            f"| {r['phase']} | {r['steps']} | {r['iterations']} | {r['per_step']:.1f} | "
            f"{r['in_failed_attempts']} | {r['cutbacks']} |"
        )
    replays = {}
    for row in a.replay:
        print(f"replay of row {row} (from t = {float(calls[row - 1]['state'].t):.4g} s):")
        replays[row] = replay(calls[row - 1])
    if a.first_steps:
        print(first_steps_table(calls, h), flush=True)
    if a.json:
        Path(a.json).write_text(
            json.dumps(
                dict(
                    phases=table,
                    total_s=total,
                    force_N=float(h["force_N"][-1]),
                    iterations=[int(v) for v in h["newton_iterations"]],
                    # the last attempt's ||R_k|| / F of each step (None: not reached), to try a
                    # stall rule on the converged attempts without a run
                    histories=[[float(v) if np.isfinite(v) else None for v in r] for r in hists],
                    replays={str(k): v for k, v in replays.items()},
                ),
                indent=1,
                default=str,
            )
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
