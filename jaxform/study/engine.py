"""Run a study's samples on worker processes and keep its table.

Where: Dask distributed.  Without an address, a ``LocalCluster`` of worker processes on
this machine (no server to start); with ``--cluster ADDRESS`` the same tasks go to that
scheduler.  Each sample is one task (``evaluate_sample``: the scene with the sample's
``--set`` overrides through :func:`jaxform.driver.run`, the responses read from its
history), so a worker that dies mid-sample (killed, out of memory) loses nothing: the
scheduler runs the task again on another worker, up to ``study.retries`` times.

The table (``results.csv``): one row per sample, appended as samples finish by this process
alone (the tasks return rows, they write nothing), so each sample appears exactly once.
``plan.csv`` holds every sample's inputs; ``--resume`` checks that the plan is unchanged
and runs only the samples the table lacks.  Floats are written with ``repr``: a row reads
back bit for bit.
"""

from __future__ import annotations

import csv
import math
import os
import re
import socket
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from jaxform.errors import ConfigError
from jaxform.study.spec import Response, Study

RESULTS = "results.csv"
PLAN = "plan.csv"
CONNECT_TIMEOUT_S = 10.0


@dataclass(frozen=True)
class Task:
    """What a worker needs for one sample (picklable)."""

    index: int
    config: object  # TOML path (str) or document (dict)
    overrides: tuple[str, ...]  # the base --set overrides, then the sample's
    inputs: tuple[str, ...]  # the input keys (gradients)
    responses: tuple[Response, ...]
    gradients: bool = False
    base: tuple[str, ...] = ()  # the base --set overrides alone (gradients)
    values: tuple[float, ...] = ()  # the sample's input values (gradients)


def response_values(result, responses) -> dict[str, float]:
    """Each response of a finished run (ValueError naming the history's columns for a
    column it lacks)."""
    h = result.history
    out = {}
    for r in responses:
        if r.reducer == "count":
            out[r.name] = float(len(result.laps))
            continue
        if r.column not in h:
            raise ValueError(
                f"response {r.text!r}: the history has no column {r.column!r}; its columns: "
                f"{', '.join(sorted(h))}"
            )
        col = np.asarray(h[r.column], dtype=float)
        reduce = {"end": lambda c: c[-1], "max": np.max, "min": np.min}[r.reducer]
        out[r.name] = float(reduce(col))
    return out


def evaluate_sample(task: Task) -> dict:
    """Run one sample: its row (inputs are added by the caller).  A failed run is a row
    with status 'failed' and the reason, never an exception (only a dying worker fails
    the task)."""
    from jaxform.driver import run
    from jaxform.precision import enable_x64

    enable_x64()
    t0 = time.perf_counter()
    row = {"sample": task.index, "status": "ok", "message": ""}
    row.update({r.name: math.nan for r in task.responses})
    try:
        result = run(task.config, task.overrides)
        row.update(response_values(result, task.responses))
    except Exception as err:  # noqa: BLE001 - any failure of a sample is its row's message
        row.update(status="failed", message=f"{type(err).__name__}: {err}")
    if task.gradients and row["status"] == "ok":
        from jaxform.study.gradients import response_gradients

        try:
            row.update(response_gradients(task))
        except Exception as err:  # noqa: BLE001 - the responses stand; the row says why
            row["message"] = f"no gradient: {type(err).__name__}: {err}"
    row["wall_s"] = time.perf_counter() - t0
    row["worker"] = f"{socket.gethostname()}:{os.getpid()}"
    return row


def gradient_columns(study: Study) -> list[str]:
    if not study.gradients:
        return []
    return [f"d_{r.name}/d_{i.key}" for r in study.responses for i in study.inputs]


def columns(study: Study) -> list[str]:
    return [
        "sample",
        *(i.key for i in study.inputs),
        *(r.name for r in study.responses),
        *gradient_columns(study),
        "status",
        "wall_s",
        "worker",
        "message",
    ]


def _cell(v) -> str:
    if isinstance(v, float):
        return repr(v)
    return " ".join(str(v).split())  # one line


class Table:
    """``results.csv`` of a study: rows appended as they come, flushed to disk each."""

    def __init__(self, path: Path, cols: list[str]):
        self.path, self.cols = path, cols
        new = not path.exists() or path.stat().st_size == 0
        if not new:
            _drop_partial_line(path)
        self.file = open(path, "a", newline="")  # noqa: SIM115 - closed in close()
        self.writer = csv.writer(self.file)
        if new:
            self.writer.writerow(cols)
            self.file.flush()

    def add(self, row: dict) -> None:
        self.writer.writerow([_cell(row.get(c, "")) for c in self.cols])
        self.file.flush()
        os.fsync(self.file.fileno())

    def close(self) -> None:
        self.file.close()


def _drop_partial_line(path: Path) -> None:
    """A study killed while writing a row leaves it without its newline: cut it off."""
    data = path.read_bytes()
    if data and not data.endswith(b"\n"):
        path.write_bytes(data[: data.rfind(b"\n") + 1])


def read_table(path) -> list[dict]:
    """The rows of a results table (strings; see :func:`as_arrays`)."""
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def as_arrays(rows: list[dict], names: list[str]) -> dict[str, np.ndarray]:
    """Float columns of the rows (empty cells: NaN)."""
    return {n: np.array([float(r[n]) if r[n] != "" else math.nan for r in rows]) for n in names}


def _write_plan(study: Study, path: Path) -> None:
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["sample", *(i.key for i in study.inputs)])
        for k, v in enumerate(study.values):
            w.writerow([k, *(repr(float(x)) for x in v)])


def _check_resume(study: Study, out: Path, resume: bool) -> set[int]:
    """The samples the folder's table holds already (resume), or ConfigError where the
    folder holds another study or a study without --resume."""
    table, plan = out / RESULTS, out / PLAN
    if not resume:
        if table.exists() and table.stat().st_size > 0:
            raise ConfigError(
                f"--out {out}: holds a study's {RESULTS} already: give --resume to run "
                f"only its missing samples, or another folder"
            )
        return set()
    if not plan.exists():
        if table.exists() and table.stat().st_size > 0:
            raise ConfigError(f"--resume: {out} has a {RESULTS} but no {PLAN}: use another --out")
        return set()
    expected = out / (PLAN + ".new")
    _write_plan(study, expected)
    same = expected.read_text() == plan.read_text()
    expected.unlink()
    if not same:
        raise ConfigError(
            f"--resume: the plan in {plan} is not this config's (inputs, plan, samples or "
            f"seed changed): use another --out"
        )
    if not table.exists():
        return set()
    _drop_partial_line(table)
    rows = read_table(table)
    with open(table, newline="") as fh:  # the header, also of a table with no row yet
        header = next(csv.reader(fh), None)
    if header is not None and header != list(columns(study)):
        raise ConfigError(f"--resume: {table} has other columns than this study's table")
    return {int(r["sample"]) for r in rows}


def check_cluster_address(address: str) -> str:
    """``tcp://host:port`` (or ``host:port``, ``tls://``...) -> the address, else
    ConfigError naming the flag and the allowed form."""
    m = re.fullmatch(r"(?:(tcp|tls|ucx|inproc)://)?([\w.\-]+|\[[0-9a-fA-F:]+\]):(\d+)", address)
    if not m or not 1 <= int(m.group(3)) <= 65535:
        raise ConfigError(
            f"--cluster {address!r}: not a Dask scheduler address: give "
            f"tcp://HOST:PORT with PORT in [1, 65535] (e.g. tcp://10.0.0.5:8786)"
        )
    return address if m.group(1) else f"tcp://{address}"


@dataclass
class Where:
    """Where the samples run: a scheduler address (None: a local cluster of ``workers``
    processes)."""

    cluster: str | None = None
    workers: int = 0  # local: worker processes (0: one per CPU core)
    client: object = None  # a Dask client the caller owns (kept open): used as it is


@dataclass
class Summary:
    """What a study did: samples run now, failed, found done, wall time."""

    total: int
    ran: int = 0
    failed: int = 0
    skipped: int = 0
    wall_s: float = 0.0
    workers: list = field(default_factory=list)


def connect(where: Where, retries: int):
    """A Dask client: to the scheduler at ``where.cluster`` (ConfigError when none answers
    in CONNECT_TIMEOUT_S), or to a new local cluster of worker processes."""
    import logging

    import dask
    from distributed import Client, LocalCluster

    dask.config.set({"distributed.scheduler.allowed-failures": retries})
    if where.client is not None:
        return where.client, None
    if where.cluster is not None:
        address = check_cluster_address(where.cluster)
        try:
            return Client(address, timeout=CONNECT_TIMEOUT_S), None
        except (OSError, TimeoutError) as err:
            raise ConfigError(
                f"--cluster {where.cluster}: no Dask scheduler answered within "
                f"{CONNECT_TIMEOUT_S:g} s ({type(err).__name__})"
            ) from None
    n = where.workers or os.cpu_count() or 1
    cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                           dashboard_address=":0", silence_logs=logging.ERROR)  # fmt: skip
    return Client(cluster), cluster


def run_study(study: Study, config, overrides, out_dir, where: Where | None = None,
              resume: bool = False, progress=None) -> Summary:  # fmt: skip
    """Run the samples the table in ``out_dir`` lacks; append each row as it finishes.

    Arguments:
        study: from :func:`jaxform.study.spec.build_study` (checked).
        config, overrides: the scene (TOML path or dict) and its base ``--set`` overrides.
        out_dir: the study's folder (plan.csv, results.csv).
        where: the scheduler or the local worker count (default: local, one per core).
        resume: run only what the table lacks (the plan must be the same).
        progress: called with (done, total, failed) after each sample.

    Returns:
        a :class:`Summary`.  Raises ConfigError before anything runs (folder, address)."""
    from distributed import as_completed

    where = where or Where()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    done = _check_resume(study, out, resume)
    todo = [i for i in range(study.n) if i not in done]
    summary = Summary(total=study.n, skipped=len(done))
    if not isinstance(config, dict):  # the document travels: workers need not see the file
        from jaxform.config import read_document

        config = read_document(config)
    t0 = time.perf_counter()
    client, cluster = connect(where, study.retries) if todo else (None, None)
    if not (out / PLAN).exists():
        _write_plan(study, out / PLAN)
    if progress:
        progress(len(done), study.n, 0)
    if not todo:
        return summary
    table = Table(out / RESULTS, columns(study))
    try:
        futures = _submit(client, study, config, overrides, todo)
        summary.workers = list(client.scheduler_info().get("workers", {}))
        for fut in as_completed(futures):
            for row in _rows_of(fut, futures[fut]):
                i = row["sample"]
                row.update(zip((x.key for x in study.inputs), map(float, study.values[i])))
                table.add(row)
                summary.ran += 1
                summary.failed += row["status"] != "ok"
                if progress:
                    progress(len(done) + summary.ran, study.n, summary.failed)
    finally:
        table.close()
        if client is not where.client:
            client.close()
        if cluster is not None:
            cluster.close()
    summary.wall_s = time.perf_counter() - t0
    return summary


def _task(study: Study, config, overrides, i: int) -> Task:
    return Task(i, config, (*overrides, *study.overrides(i)),
                tuple(x.key for x in study.inputs), study.responses, study.gradients,
                tuple(overrides), tuple(map(float, study.values[i])))  # fmt: skip


def _submit(client, study: Study, config, overrides, todo: list[int]) -> dict:
    """One task per sample, or per chunk of study.batch samples: {future: its samples}."""
    token = f"{os.getpid()}-{time.time_ns()}"
    if not study.batch:
        return {client.submit(evaluate_sample, _task(study, config, overrides, i),
                              key=f"jaxform-sample-{token}-{i}", pure=False): (i,)
                for i in todo}  # fmt: skip
    from jaxform.study.batched import BatchTask, evaluate_batch

    out = {}
    for k in range(0, len(todo), study.batch):
        chunk = tuple(todo[k : k + study.batch])
        task = BatchTask(chunk, study.batch, config, tuple(overrides),
                         tuple(x.key for x in study.inputs),
                         tuple(tuple(map(float, study.values[i])) for i in chunk),
                         study.responses, study.gradients)  # fmt: skip
        key = f"jaxform-batch-{token}-{chunk[0]}-{chunk[-1]}"
        out[client.submit(evaluate_batch, task, key=key, pure=False)] = chunk
    return out


def _rows_of(fut, samples: tuple[int, ...]) -> list[dict]:
    """The finished task's rows, or failed rows where its workers died (retries spent)."""
    try:
        got = fut.result()
        return got if isinstance(got, list) else [got]
    except Exception as err:  # noqa: BLE001 - KilledWorker, a lost scheduler: the row says
        return [{"sample": i, "status": "failed", "wall_s": math.nan, "worker": "",
                 "message": f"{type(err).__name__}: {err}"} for i in samples]  # fmt: skip
