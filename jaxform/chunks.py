"""The compiled chunks as the host loop runs them, and why a run stops.

:func:`run_on` runs one chunk of steps (:func:`jaxform.stepping.run_chunk`, through the
stored program where there is one, :mod:`jaxform.program_store`) on a mesh of the run
(:class:`jaxform.adaptation.OnMesh`), retrying the steps one at a time when the linear
solver raises on a singular Jacobian (:func:`chunk`); :func:`converged_rows` reads its
converged rows and the failure that ends the run; :func:`failure_message` and
:func:`host_failure` are the one-line messages of a failed step and of an error raised
between the chunks.
"""

from __future__ import annotations

from dataclasses import replace

import jax
import jax.numpy as jnp
import numpy as np
from jax.errors import JaxRuntimeError

from jaxform import program_store
from jaxform.adaptation import OnMesh, absolute
from jaxform.presses import capacity_message
from jaxform.rezone import corner_qualities
from jaxform.scenes import Inputs, Scene
from jaxform.status import CAUSES, NEWTON_NOT_CONVERGED, NOT_FINITE, OK, SINGULAR
from jaxform.stepping import SimState, StepControl, Stepper, output_fields, run_chunk
from jaxform.triggers import CAPACITY


def failure_message(scene: Scene, inp: Inputs, state: SimState, step: int | None, row) -> str:
    """Why step ``step`` (None: the step from ``state``) failed, where: the cause, the
    time reached, the smallest step tried, and the worst element of the last converged
    mesh (its centre and corner quality), which names the place when the cause is
    geometric (an element folding)."""
    pos = scene.model.nodal_positions(np.asarray(state.x), np.asarray(inp.coords), scene.idx)
    elements = np.asarray(scene.mesh.elements)
    q = corner_qualities(np.asarray(pos), elements).min(axis=1)
    e = int(np.argmin(q))
    centre = np.asarray(pos)[elements[e]].mean(axis=0)
    h_min = scene.dt * 0.5**scene.max_cutbacks
    t = float(state.t)
    name = "the step" if step is None else f"step {step}"
    return (
        f"{name} (last converged time {t:g} s, target time "
        f"{min(t + h_min, scene.t_end):g} s) failed after {int(row['cutbacks'])} attempts, "
        f"the last at the smallest step dt = {h_min:g} s (time.dt_s / 2**solver.max_cutbacks)"
        f"{_continued(scene, int(row['code']))}: "
        f"{CAUSES.get(int(row['code']), 'unknown')}{_residuals(scene, row)}; worst element {e} at "
        f"({centre[0]:.4g}, {centre[1]:.4g}) mm, corner quality {q[e]:.3g}{_remedy(scene, q[e])}"
    )


def _continued(scene: Scene, code: int) -> str:
    """How long Newton went on at the smallest step, for the failure message."""
    k = scene.continuations
    if k == 0 or code != NEWTON_NOT_CONVERGED:
        return ""
    return (
        f" and Newton continued there {k} times (solver.smallest_step_continuations; "
        f"{(k + 1) * scene.newton.max_iterations} iterations)"
    )


def _residuals(scene: Scene, row) -> str:
    """How the last Newton solve of a step that did not converge went: its first, last and
    least relative residual against ``solver.rtol`` (a stall a little above the tolerance
    and a solve that never came near it call for different remedies)."""
    hist = np.asarray(row.get("hist", ()), dtype=float).ravel()
    e = hist[np.isfinite(hist)]
    if int(row["code"]) != NEWTON_NOT_CONVERGED or e.size == 0:
        return ""
    return (
        f" (the last solve's residual ||R||/F went {e[0]:.3g} -> {e[-1]:.3g} in {e.size} "
        f"iterations, least {e.min():.3g}; solver.rtol = {scene.newton.rtol:g})"
    )


def _remedy(scene: Scene, quality: float) -> str:
    """The setting that lets a run stopped by a distorted element go on: a new mesh
    before the elements fold (remeshing, or a higher trigger than the one set)."""
    if quality >= 0.3:
        return ""
    rm = scene.remesh
    if rm is not None and rm.on and rm.quality_below < 0.3:
        return (
            f"; remesh.quality_below = {rm.quality_below:g} fired too late: 0.3 replaces the "
            f"mesh earlier"
        )
    if rm is not None and rm.on:
        return "; remesh.element_size_mm smaller (a finer new mesh) may let the run go on"
    if scene.rezone_quality > 0.0:
        return (
            "; the mesh folds faster than rezoning can mend it: remeshing "
            "(mesh.rezone_quality = 0, remesh.quality_below = 0.3) replaces it"
        )
    return "; to go on, let the run replace the mesh before it folds: remesh.quality_below = 0.3"


def host_failure(row: dict, err: Exception) -> str:
    """The one line for an error raised between the compiled chunks (a remesh, a
    transfer, the history): where the run was and what was raised."""
    return (
        f"the run stopped after the converged time {float(row['time_s']):g} s (stroke "
        f"{float(row['stroke_mm']):.4g} mm): {type(err).__name__}: {err}"
    )


def converged_rows(mesh: OnMesh, state: SimState, outs: dict, first: int):
    """(rows, failure) of a chunk run on ``mesh`` (:func:`run_on`) whose first step is
    history row ``first``: its converged rows (the unknowns measured from the scene's
    reference, ``dt_s``, the adaptation's columns at 0) and why the run ends there, or
    None: a step that failed at the smallest step size or converged to a state that is not
    finite, or the press capacity reached (the run ends on that row)."""
    rows = []
    for j in range(len(outs["active"])):
        row, n = {k: v[j] for k, v in outs.items()}, first + len(rows)
        if not row["active"]:
            break
        if int(row["code"]) == OK and not _finite(row):
            row["code"] = NOT_FINITE  # converged to a meaningless (overflowed) state
        if int(row["code"]) != OK:
            return rows, failure_message(mesh.scene, mesh.inputs, state, n, row)
        row.update(x=absolute(mesh, row["x"]), dt_s=float(row["h_used"]), rezoned=0,
                   remeshed=0, new_nodes=0)  # fmt: skip
        rows.append(row)
        if int(row["pause_cause"]) & CAPACITY:  # the press stalls: the run ends on this row
            capacity = mesh.scene.press.capacity_N
            return rows, capacity_message(capacity, float(row["stroke_mm"]), n)
    return rows, None


def run_on(mesh: OnMesh, state: SimState, control: StepControl, fac):
    """One compiled chunk of ``mesh``'s scene (:func:`chunk`) from ``state`` on it: (state,
    control, host outputs, factorization), the state and outputs back on the mesh's scene."""
    state, control, outs, fac = chunk(
        mesh.stepped, mesh.stepper, mesh.enter(state), control, mesh.step_inputs, fac
    )
    state, outs = mesh.leave(state, jax.device_get(outs))
    return state, control, outs, fac


def _finite(row: dict) -> bool:
    """Whether a converged step's force and unknowns are finite numbers."""
    return bool(np.isfinite(row["force_N"]) and np.all(np.isfinite(row["x"])))


def _singular(err: Exception) -> bool:
    return "singular" in str(err)


def _run_chunk(stepper: Stepper, state, control, inp: Inputs, idx, n: int, fac):
    """:func:`run_chunk`, through the stored program of its stepper and chunk length where
    there is one (:mod:`jaxform.program_store`: a warm start without tracing)."""
    return program_store.call(
        "run_chunk",
        f"{stepper!r}|n={n}",
        lambda s, c, i, x, f: run_chunk(stepper, s, c, i, x, n, f),
        state,
        control,
        inp,
        idx,
        fac,
    )


def chunk_steps(scene: Scene, state: SimState) -> int:
    """The steps of a chunk from ``state``: ``scene.chunk``, fewer where their output
    fields (:func:`jaxform.stepping.output_fields`, one array per field over the steps,
    held while the chunk runs and until the host has read them) would take more than
    ``scene.chunk_output_mb``; at least one."""
    per_step = sum(a.size * a.dtype.itemsize for a in output_fields(state).values())
    return max(1, min(scene.chunk, int(scene.chunk_output_mb * 1e6 // max(per_step, 1))))


def after_singular(stepper: Stepper) -> Stepper:
    """The stepper of the steps retried after a singular Jacobian: the corner-contact
    facets open until an arc reaches past their nodes' own depth in the die
    (:attr:`jaxform.contact.ContactLaw.facets_by_node_depth`), the same law at a
    converged state.  Unchanged where the mesh has no corner-contact facets."""
    model = stepper.model
    if not model.layout.n_facets:
        return stepper
    law = replace(model.contact, facets_by_node_depth=True)
    return replace(stepper, model=replace(model, contact=law))


def chunk(scene: Scene, stepper: Stepper, state: SimState, control, inp: Inputs, fac):
    """:func:`run_chunk` over :func:`chunk_steps` steps.  A linear solver that finds the
    Jacobian singular raises (klujax does, instead of returning a status); then the steps
    are retried one at a time by :func:`after_singular`'s stepper, the step halved after
    each singular attempt as after any failed one, down to the smallest step, where the
    outputs carry the code SINGULAR."""
    try:  # blocking: an error of the asynchronous run surfaces here, not at the caller
        return jax.block_until_ready(
            _run_chunk(stepper, state, control, inp, scene.idx, chunk_steps(scene, state), fac)
        )
    except JaxRuntimeError as err:
        if not _singular(err):
            raise
    # the factorization passed in may have been freed inside the failed chunk: a new one
    n = scene.model.layout.n_dofs
    h_min = scene.dt * 0.5**scene.max_cutbacks
    h, cutbacks = float(control.h), 0
    stepper = after_singular(stepper)
    while True:
        fac = scene.newton.variant.factorization(scene.linear, n, state.x.dtype)
        try:
            st, ctl, outs, fac = jax.block_until_ready(
                _run_chunk(
                    stepper, state, replace(control, h=jnp.asarray(h)), inp, scene.idx, 1, fac
                )
            )
        except JaxRuntimeError as err:
            if not _singular(err):
                raise
            cutbacks += 1
            if h <= h_min * (1.0 + 1e-9):
                failed = dict(active=np.array([True]), code=np.array([SINGULAR]),
                              cutbacks=np.array([cutbacks]))  # fmt: skip
                return state, control, failed, None
            h = max(0.5 * h, h_min)
            continue
        return st, ctl, dict(outs, cutbacks=outs["cutbacks"] + cutbacks), fac
