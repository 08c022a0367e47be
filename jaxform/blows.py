"""Energy-limited ram motion: the strokes of a screw press and the blows of a hammer.

Model (quasi-static finite elements; the ram decelerates with the work it does).  Each
blow has the energy E (``press.energy_J``, the ram's kinetic energy at impact) of which
efficiency x E is done as work on the part, W = integral of F d(stroke) (F: the ram force
on the whole workpiece, the stroke: the ram's).  A blow is ``steps_per_blow`` = N load
steps.  Step j of a blow (j = 0 .. N-1) starts with the work L = efficiency x E - W still
to do and aims at the share dW = L / (N - j):

1. predictor: the stroke increment ds_a with 1/2 (2 F_n + k ds) ds = dW, F_n the force at
   the start of the step and k the last secant stiffness (dF / d stroke), solved;
2. corrector: k_a = (F_a - F_n) / ds_a from the predictor's force F_a, ds_b from the same
   quadratic with k_a (or 2 dW / (F_n + F_a) where that is less: a force curve that bends
   over, the elastic-plastic knee of the first step), solved again from the predictor's
   solution;
3. second corrector: ds_c from the force line through the two solves (a secant step on
   work(ds) = dW; the ram slowing to rest bends the force curve in a blow's last step,
   since the material's rate falls), solved; this is the step.

The work of the step, 1/2 (F_n + F_b) ds_b (the trapezoid rule of the force-stroke
curve), is counted as done: what one step misses the next ones make up, and the last step
of a blow aims at all that is left.  Its force curve is smooth over a step, so its work
lands on efficiency x E to second order in the step (tests: 0.5 %).

Time (the viscoplastic rate).  The ram speed follows the work left, v = v0 sqrt(L /
(efficiency x E)) (:meth:`jaxform.presses.EnergyPress.speed`; v0 the impact speed), so a
step's time is ds / mean speed, 2 ds / (v(L) + v(L - dW)), with v = 0 at the end of the
blow (a uniform deceleration over the last step: finite).  Between blows the die stays on
the part and the next blow starts at once from the state the last left (no unloading, no
rest between blows).

Everything is one ``lax.scan`` over the fixed number of steps (blows x N), each step three
implicitly differentiated Newton solves (:func:`jaxform.stepping.solve_step`): the forward
run and the gradient run are the same function (:func:`blow_run`), so ``jax.grad`` of any
output (the final height after the blows) with respect to the blow energy, the
efficiency, the impact speed or any other input is exact for this discrete scheme.  No
cutback: a step that does not converge leaves its code, and :func:`simulate_blows` stops
the history before it.
"""

from __future__ import annotations

from dataclasses import replace
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from jaxform.forming_outputs import damage_columns
from jaxform.presses import EnergyPress, capacity_message, first_over_capacity
from jaxform.scenes import Inputs, Scene
from jaxform.status import CAUSES, OK
from jaxform.stepping import (
    Stepper,
    contact_step,
    converged_state,
    die_force,
    initial_state,
    solve_step,
    step_outputs,
    stepper_of,
)
from jaxform.xla_options import jit

SOLVES = 3  # Newton solves of a step: the predictor and two secant corrections
FIRST_STROKE = 0.01  # the first step's stroke guess, as a fraction of the reference height


def _stroke_for_work(force, stiffness, work):
    """The stroke increment ds with 1/2 (2 F + k ds) ds = work (the stable root)."""
    disc = jnp.maximum(force**2 + 2.0 * stiffness * work, 0.25 * force**2)
    return 2.0 * work / jnp.maximum(force + jnp.sqrt(disc), 1e-300)


def _stroke_for_line(c0, slope, work):
    """The stroke increment ds with 1/2 (c0 + slope ds) ds = work (the force at the step's
    start plus a force line through the step, F_n + F(ds) = c0 + slope ds)."""
    disc = jnp.maximum(c0**2 + 8.0 * slope * work, 0.25 * c0**2)
    return 4.0 * work / jnp.maximum(c0 + jnp.sqrt(disc), 1e-300)


def with_path(die, times, travel):
    """The die (a RigidDie or DieSet) with its top die on the path table (times, travel)."""
    return die.replace_top(lambda d: replace(d, path_time_s=times, path_travel_mm=travel))


@partial(jit, static_argnums=(0, 4, 5))
def _blow_scan(stepper: Stepper, inputs: Inputs, press: EnergyPress, idx, factor: float,
               first_mm: float):  # fmt: skip
    model = stepper.model
    n_b = press.steps_per_blow
    target = press.work_per_blow_Nmm
    state0 = initial_state(model, inputs)

    def step(carry, xs):
        st, d, force, k, work, x_per_mm = carry
        j, first, last = xs
        work = jnp.where(first, 0.0, work)
        # an earlier step that overshot leaves a sliver to do, never nothing (a stroke of
        # 0 and a ram at rest would make the step's time infinite)
        dw = jnp.maximum((target - work) / (n_b - j), 1e-6 * target / n_b)
        left = jnp.maximum(target - work, dw)
        v_start = press.speed(left)
        # (no sqrt at 0 on the last step: its derivative would be infinite)
        v_end = jnp.where(last, 0.0, press.speed(jnp.where(last, left, left - dw)))

        def path(ds):
            t1 = st.t + 2.0 * ds / (v_start + v_end)
            inp = replace(inputs, die=with_path(inputs.die, jnp.stack([st.t, t1]),
                                                jnp.stack([d, d + ds / factor])))  # fmt: skip
            return t1, inp

        def solve(c, i):
            """Solve at the stroke increment c['ds'] and choose the next one on the force
            line through this solve and the last point (the step's start, then the
            previous solve); the first choice is at most the one that holds this solve's
            force over the step (a force curve that bends over: the elastic-plastic
            knee of the first step, where the secant under-predicts the force)."""
            ds, ok = c["ds"], c["code"] == OK
            guess = jnp.where(ok, st.x + (c["x"] - st.x) * (ds / c["ds_prev"]), st.x)
            t1, inp = path(ds)
            sol = solve_step(stepper, st, t1, inp, idx, x_guess=guess)
            f = die_force(model, sol.x, inp, t1, idx)
            gap = ds - c["ds_line"]
            apart = jnp.abs(gap) > 1e-6 * ds
            slope = jnp.where(apart, (f - c["f_line"]) / jnp.where(apart, gap, 1.0), c["k"])
            slope = jnp.where(i == 0, jnp.maximum(slope, 0.0), slope)
            ds_next = _stroke_for_line(force + f - slope * ds, slope, dw)
            ds_next = jnp.where(i == 0, jnp.minimum(ds_next, 2.0 * dw / (force + f)), ds_next)
            its = c["its"] + sol.iterations
            return dict(ds=ds_next, ds_prev=ds, ds_line=ds, f_line=f, k=slope, x=sol.x,
                        gauss=sol.gauss, code=sol.code, its=its, ds_used=ds, f=f), None  # fmt: skip

        ds_a = _stroke_for_work(force, k, dw)
        zero = jnp.zeros_like(force)
        # the predictor's guess: the last step's displacement per mm of stroke
        c0 = dict(ds=ds_a, ds_prev=ds_a, ds_line=zero, f_line=force, k=k,
                  x=st.x + ds_a * x_per_mm, gauss=st.gauss, code=jnp.asarray(OK),
                  its=jnp.asarray(0), ds_used=zero, f=zero)  # fmt: skip
        c, _ = jax.lax.scan(solve, c0, jnp.arange(SOLVES))
        ds_b, f_b = c["ds_used"], c["f"]
        t1, inp = path(ds_b)
        cstep = contact_step(model, st, inp, idx)
        new = converged_state(model, st, c["x"], c["gauss"], t1, inp, cstep, idx)
        work_new = work + 0.5 * (force + f_b) * ds_b
        k_new = jnp.maximum((f_b - force) / ds_b, 0.0)
        per_mm = jax.lax.stop_gradient((c["x"] - st.x) / ds_b)
        # the row as every step records it (fields, damage, wear, each die's force), the
        # stroke and force as this step landed them (what the unused ones cost is removed
        # by the compiler)
        out = dict(step_outputs(model, new, inp, idx, stepper.symmetric_z),
                   stroke_mm=factor * (d + ds_b / factor), force_N=f_b,
                   blow_work_Nmm=work_new, ram_speed_mm_s=v_end, code=c["code"],
                   iterations=c["its"])  # fmt: skip
        return (new, d + ds_b / factor, f_b, k_new, work_new, per_mm), out

    j = jnp.tile(jnp.arange(n_b), press.blows)
    first, last = j == 0, j == n_b - 1
    k0 = 2.0 * (target / n_b) / first_mm**2  # the first guess: FIRST_STROKE x height
    zero = jnp.zeros((), dtype=state0.x.dtype)
    init = (state0, zero, zero, k0, zero, jnp.zeros_like(state0.x))
    final, outs = jax.lax.scan(step, init, (j, first, last))
    return final[0], outs


def blow_run(scene: Scene, inputs: Inputs | None = None, press: EnergyPress | None = None):
    """(final state, per-step outputs) of the scene's blows (traceable, differentiable in
    ``inputs`` and ``press``; defaults: the scene's).  The outputs are arrays over the
    blows x steps_per_blow steps: time_s, stroke_mm (the ram's), force_N, blow_work_Nmm
    (the work of the blow so far), ram_speed_mm_s (at the step's end), code, iterations,
    the fields."""
    inputs = scene.inputs if inputs is None else inputs
    press = scene.press if press is None else press
    stepper = stepper_of(scene, differentiable=True)
    factor = 2.0 if scene.symmetric_z else 1.0
    first_mm = FIRST_STROKE * scene.workpiece.reference_height_mm
    # the capacity and the name are the host's: runs that differ in them share a program
    press = replace(press, capacity_N=0.0, name="")
    return _blow_scan(stepper, inputs, press, scene.idx, factor, first_mm)


def final_height(scene: Scene, outs) -> jax.Array:
    """The workpiece height after the last step (mm): the reference height less the ram
    stroke (traceable)."""
    return scene.workpiece.reference_height_mm - outs["stroke_mm"][-1]


def blows_to_height(history: dict, height_mm: float, reference_mm: float) -> int | None:
    """The number of blows after which the height (reference - stroke) is at most
    ``height_mm`` (None: the run's blows do not get there)."""
    ends = np.flatnonzero(np.diff(history["blow"]) != 0)  # the last row of each blow
    ends = np.r_[ends[1:], len(history["blow"]) - 1]
    heights = reference_mm - history["stroke_mm"][ends]
    hit = np.flatnonzero(heights <= height_mm)
    return None if hit.size == 0 else int(hit[0]) + 1


def simulate_blows(scene: Scene, progress=None):
    """Run the scene's screw-press stroke or hammer blows (:func:`blow_run`) and return a
    :class:`jaxform.simulation.Result`, as :func:`jaxform.simulation.simulate` does (it
    calls this for such a scene).  History columns besides the usual ones: ``blow`` (the
    blow of the row, 0 for the initial row), ``blow_work_Nmm`` (the work done on the part
    in that blow so far), ``ram_speed_mm_s``.  A step that fails, or one at which the
    ram force reaches the press capacity, ends the history there and raises
    :class:`jaxform.simulation.SimulationError` with the history up to it."""
    from jaxform.simulation import (
        FIELD_KEYS,
        Result,
        Segment,
        SimulationError,
        _history,
        _initial_row,
    )

    state0 = initial_state(scene.model, scene.inputs)
    final, outs = jax.device_get(jax.block_until_ready(blow_run(scene)))
    press = scene.press
    n = len(outs["time_s"])
    blow = np.repeat(np.arange(1, press.blows + 1), press.steps_per_blow)
    codes = np.asarray(outs["code"])
    bad = np.flatnonzero(codes != OK)
    stop = n if bad.size == 0 else int(bad[0])
    failure = None
    if bad.size:
        cause = CAUSES.get(int(codes[stop]), "unknown")
        failure = (
            f"{press.name}: step {stop + 1} (blow {blow[stop]}) failed: {cause}; "
            "raise press.steps_per_blow"
        )
    over = first_over_capacity(outs["force_N"][:stop], press.capacity_N)
    if over is not None:
        stop = over + 1
        failure = capacity_message(press.capacity_N, float(outs["stroke_mm"][over]), over + 1)
    times = np.r_[0.0, outs["time_s"][:stop]]
    travel = np.r_[0.0, outs["stroke_mm"][:stop]] / (2.0 if scene.symmetric_z else 1.0)
    if stop == 0:  # a table needs two rows
        times, travel = np.array([0.0, 1.0]), np.zeros(2)
    die = with_path(scene.inputs.die, jnp.asarray(times), jnp.asarray(travel))
    run_scene = replace(scene, inputs=replace(scene.inputs, die=die), t_end=float(times[-1]))
    rows = [dict(_initial_row(run_scene, state0), blow=0, blow_work_Nmm=0.0,
                 ram_speed_mm_s=float(press.impact_speed_mm_s))]  # fmt: skip
    for i in range(stop):
        row = {k: v[i] for k, v in outs.items()}
        row.update(dt_s=float(times[i + 1] - times[i]), factorizations=row["iterations"],
                   cutbacks=0, mesh_quality=np.nan, rezoned=0, remeshed=0, new_nodes=0,
                   pause_cause=0, blow=int(blow[i]))  # fmt: skip
        row.update(damage_columns(run_scene, row["x"], row["damage"]))
        rows.append(row)
        if progress is not None:
            progress(dict(step=i + 1, n_steps=n, chunk_end=i == stop - 1, remeshed=0,
                          remesh_trigger="", iterations=int(row["iterations"]), cutbacks=0,
                          **{k: float(row[k]) for k in ("time_s", "stroke_mm", "force_N",
                                                        "dt_s")}))  # fmt: skip
    fields = {k: np.stack([np.asarray(r[k]) for r in rows]) for k in FIELD_KEYS}
    history = _history([Segment(0, run_scene)], rows, fields)
    for k in ("blow", "blow_work_Nmm", "ram_speed_mm_s"):
        history[k] = np.array([float(r[k]) for r in rows])
    result = Result(history=history, fields=fields, scene=run_scene, final_state=final,
                    newton_histories=np.zeros((stop, 0)), failure=failure,
                    inputs=run_scene.inputs, segments=[Segment(0, run_scene)])  # fmt: skip
    if failure:
        raise SimulationError(failure, result)
    return result
