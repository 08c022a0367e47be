"""Batched samples: B samples of one scene as one vmapped program (:mod:`jaxform.batch`).

With ``study.batch = B`` a task holds B samples.  Its worker evaluates them as designs of
the base scene's design problem (:mod:`jaxform.study.gradients`: the study's inputs in
the friction, speed and thermal groups), all at once through
:class:`jaxform.batch.BatchProblem`: one compiled program per worker for every chunk (the
last chunk is padded to B with copies of its last sample and trimmed).  The samples share
the mesh (no input changes it) and the base scene's fixed step schedule (scaled in time by
each sample's ram speed), so the responses are those of the differentiable model, not of
each sample's own adaptive run (``study.batch = 0``): they differ by the time
discretization.  A sample whose run fails in its lane is a failed row; the others stand.
"""

from __future__ import annotations

import os
import socket
import time
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np

from jaxform.study.gradients import ResponseObjective, _problem, design_point, physical_gradient

_BATCHES: dict = {}  # id of the design problem -> its BatchProblem


@dataclass(frozen=True)
class BatchTask:
    """B samples for one worker (picklable)."""

    indices: tuple[int, ...]
    size: int  # the batch size the program is compiled for (chunks are padded to it)
    config: object
    base: tuple[str, ...]  # the base --set overrides
    inputs: tuple[str, ...]
    values: tuple[tuple[float, ...], ...]  # per sample, per input
    responses: tuple
    gradients: bool = False


def _batch(problem):
    from jaxform.batch import BatchProblem

    if id(problem) not in _BATCHES:
        _BATCHES[id(problem)] = BatchProblem(problem)
    return _BATCHES[id(problem)]


def _lane(traj, b: int):
    cols = ("time_s", "stroke_mm", "force_N", "friction_work_Nmm", "temperature_K")
    return SimpleNamespace(**{c: None if getattr(traj, c) is None else getattr(traj, c)[b]
                              for c in cols})  # fmt: skip


def _padded(designs: list, size: int) -> list:
    return designs + [designs[-1]] * (size - len(designs))


def evaluate_batch(task: BatchTask) -> list[dict]:
    """The rows of a chunk of samples (inputs added by the caller); a failed lane is a
    failed row with its step and cause, a failed chunk fails each of its rows."""
    from jaxform.batch import stack_designs
    from jaxform.precision import enable_x64
    from jaxform.status import CAUSES, OK

    enable_x64()
    t0 = time.perf_counter()
    rows = [{"sample": i, "status": "ok", "message": ""} for i in task.indices]
    for row in rows:
        row.update({r.name: float("nan") for r in task.responses})
    try:
        problem = _problem(task.config, task.base, task.inputs, task.responses[0])
        points = [design_point(problem, dict(zip(task.inputs, v))) for v in task.values]
        designs = stack_designs(_padded([d for d, _ in points], task.size))
        _, traj = _batch(problem).value_per_design(designs)
        codes = np.asarray(traj.codes)
        for b, row in enumerate(rows):
            bad = np.flatnonzero(codes[b] != OK)
            if bad.size:
                k = int(bad[0])
                row.update(status="failed", message=f"batched run: step {k + 1} failed: "
                           f"{CAUSES.get(int(codes[b, k]), 'unknown')}")  # fmt: skip
                continue
            lane = _lane(traj, b)
            for r in task.responses:
                row[r.name] = float(ResponseObjective(r.column, r.reducer)(lane, None))
        if task.gradients:
            _gradients(task, rows, [s for _, s in points])
    except Exception as err:  # noqa: BLE001 - any failure of a chunk is each row's message
        for row in rows:
            row.update(status="failed", message=f"{type(err).__name__}: {err}")
    wall = (time.perf_counter() - t0) / len(rows)
    for row in rows:
        row.update(wall_s=wall, worker=f"{socket.gethostname()}:{os.getpid()}")
    return rows


def _gradients(task: BatchTask, rows: list[dict], scales: list[dict]) -> None:
    """Gradient columns of the chunk's successful rows: one batched value-and-gradient
    program per response."""
    from jaxform.batch import stack_designs

    ok = [b for b, row in enumerate(rows) if row["status"] == "ok"]
    if not ok:
        return
    for r in task.responses:
        problem = _problem(task.config, task.base, task.inputs, r)
        designs = [design_point(problem, dict(zip(task.inputs, task.values[b])))[0] for b in ok]
        _, grads, _ = _batch(problem).value_and_grad(stack_designs(_padded(designs, task.size)))
        for j, b in enumerate(ok):
            lane = {name: np.asarray(g)[j] for name, g in grads.items()}
            phys = physical_gradient(problem, lane, scales[b])
            rows[b].update({f"d_{r.name}/d_{k}": phys[k] for k in task.inputs})
