"""A study's samples run on Dask worker processes: each row equals the single run with the
same --set overrides, an interrupted table resumes with only what is missing, and (slow) a
worker killed mid-study loses no sample and duplicates none.

Scene: the README's coarse seed (3 x 3 elements, 10 % reduction, time.dt_s = 2.5 s), whose
compiled programs the persistent cache of the test run shares (tests/conftest.py sets
JAXFORM_CACHE_DIR, which the worker processes inherit)."""

import logging
import os
import shutil
import signal
from pathlib import Path

import numpy as np
import pytest
from experiment_loader import experiment

from jaxform.driver import run
from jaxform.study.engine import RESULTS, Where, read_table, response_values, run_study
from jaxform.study.spec import build_study

SEED = str(Path(__file__).resolve().parents[1] / "configs" / "upsetting_seed.toml")
SMALL = ["mesh.nr=3", "mesh.nz=3", "die.reduction=0.1", "time.dt_s=2.5",
         "output.fields=false", "output.plots=false"]  # fmt: skip
STUDY = [
    'study.inputs=["die.speed_mm_s = uniform(0.06, 0.15)", '
    '"billet.diameter_mm = levels(4.5, 5.5)"]',
    "study.samples=3",
    "study.seed=5",
    'study.responses=["force_N:max", "force_N:end", "friction_work_Nmm:end", "laps"]',
]


def _cluster(n: int):
    from distributed import Client, LocalCluster

    cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                           dashboard_address=":0", silence_logs=logging.ERROR)  # fmt: skip
    return Client(cluster), cluster


@pytest.fixture(scope="module")
def client():
    client, cluster = _cluster(1)
    yield client
    client.close()
    cluster.close()


@pytest.fixture(scope="module")
def finished(client, tmp_path_factory):
    """The study run once on one worker: (study, its folder)."""
    study = build_study(SEED, SMALL + STUDY)
    out = tmp_path_factory.mktemp("study")
    summary = run_study(study, SEED, SMALL + STUDY, out, Where(client=client))
    assert (summary.ran, summary.failed, summary.skipped) == (3, 0, 0)
    return study, out


def test_rows_equal_the_single_runs(finished):
    """Reference: jaxform.driver.run (what jaxform run does) of the base scene with the
    sample's values as --set overrides, in this process; tolerance 1e-12 relative (the
    table holds repr floats: the same program gives the same bits)."""
    study, out = finished
    rows = sorted(read_table(out / RESULTS), key=lambda r: int(r["sample"]))
    assert [int(r["sample"]) for r in rows] == [0, 1, 2]
    for i, row in enumerate(rows):
        assert row["status"] == "ok" and row["message"] == ""
        for inp, v in zip(study.inputs, study.values[i]):
            assert float(row[inp.key]) == v
        single = response_values(run(SEED, SMALL + study.overrides(i)), study.responses)
        for name, ref in single.items():
            np.testing.assert_allclose(float(row[name]), ref, rtol=1e-12, atol=1e-12)
    # the inputs really changed the runs: three different peak forces
    assert len({row["force_N_max"] for row in rows}) == 3


def test_resume_runs_only_the_missing_samples(finished, client, tmp_path):
    """An interrupted study: its table holds sample rows 0..k and a half-written line.
    --resume runs the others only; each sample then appears once, the rerun rows equal
    the first run's (1e-12)."""
    study, done = finished
    shutil.copy(done / "plan.csv", tmp_path / "plan.csv")
    lines = (done / RESULTS).read_text().splitlines(keepends=True)
    (tmp_path / RESULTS).write_text(lines[0] + lines[1] + lines[2][:15])  # header, 1 row, torn
    kept = int(lines[1].split(",")[0])
    seen = []
    summary = run_study(study, SEED, SMALL + STUDY, tmp_path, Where(client=client), resume=True,
                        progress=lambda d, n, f: seen.append((d, n, f)))  # fmt: skip
    assert (summary.ran, summary.skipped, summary.failed) == (2, 1, 0)
    assert seen[0] == (1, 3, 0) and seen[-1] == (3, 3, 0)
    rows = {int(r["sample"]): r for r in read_table(tmp_path / RESULTS)}
    assert len(read_table(tmp_path / RESULTS)) == 3 and set(rows) == {0, 1, 2}
    first = {int(r["sample"]): r for r in read_table(done / RESULTS)}
    for i in set(rows) - {kept}:
        for r in study.responses:
            np.testing.assert_allclose(float(rows[i][r.name]), float(first[i][r.name]),
                                       rtol=1e-12)  # fmt: skip
    again = run_study(study, SEED, SMALL + STUDY, tmp_path, Where(client=client), resume=True)
    assert (again.ran, again.skipped) == (0, 3)


def test_a_failed_sample_is_a_row_with_its_message(client, tmp_path):
    """A response column the history lacks: the sample fails, its row says why (the
    history's columns), the study goes on."""
    sets = SMALL + [*STUDY[:1], "study.samples=1", 'study.responses=["no_such_column:end"]']
    study = build_study(SEED, sets)
    summary = run_study(study, SEED, sets, tmp_path, Where(client=client))
    (row,) = read_table(tmp_path / RESULTS)
    assert summary.failed == 1 and row["status"] == "failed"
    assert "no column 'no_such_column'" in row["message"] and "force_N" in row["message"]
    assert row["no_such_column_end"] == "nan"


@pytest.mark.slow
def test_a_killed_worker_loses_no_sample(tmp_path):
    """A local cluster of 2 workers runs 8 samples of a slower scene (100 steps each);
    after the first row, the worker busy with a sample is killed (SIGKILL).  Reference: the
    scheduler's record of which worker processes which task; the table must hold every
    sample exactly once, all ok, the killed worker's sample rerun by another process."""
    sets = SMALL + ["time.dt_s=0.1", *STUDY[:1], "study.samples=8", "study.seed=1",
                    'study.responses=["force_N:max"]']  # fmt: skip
    study = build_study(SEED, sets)
    client, cluster = _cluster(2)
    killed = {}

    def kill_one(done, total, failed):
        if done < 1 or killed:
            return
        busy = {w: keys for w, keys in client.processing().items() if keys}
        worker, keys = next(iter(busy.items()))
        pid = client.run(os.getpid, workers=[worker])[worker]
        killed.update(pid=pid, samples={int(str(k).rsplit("-", 1)[1]) for k in keys})
        os.kill(pid, signal.SIGKILL)

    try:
        summary = run_study(study, SEED, sets, tmp_path, Where(client=client), progress=kill_one)
    finally:
        client.close()
        cluster.close()
    rows = read_table(tmp_path / RESULTS)
    ids = [int(r["sample"]) for r in rows]
    assert killed and sorted(ids) == list(range(8)), (killed, ids)
    assert summary.failed == 0 and all(r["status"] == "ok" for r in rows)
    by_id = {int(r["sample"]): r for r in rows}
    for i in killed["samples"]:
        assert not by_id[i]["worker"].endswith(f":{killed['pid']}")


def test_sensitivities_and_figures_of_the_table(finished, tmp_path):
    """The analysis of the finished table: a record per (response, input), ranks 1..2 per
    response, the billet diameter ranked first for the peak force (reference: the force
    scales with the cross-section, (5.5/4.5)^2 = 1.49 between the two levels, against a
    rate effect of a few per cent over the speed range), the three figures written."""
    from jaxform.study.analysis import sensitivities, write_figures, write_sensitivities

    study, out = finished
    shutil.copytree(out, tmp_path / "s")
    records = sensitivities(study, read_table(tmp_path / "s" / RESULTS))
    assert len(records) == len(study.responses) * len(study.inputs)
    peak = {r["input"]: r for r in records if r["response"] == "force_N_max"}
    assert sorted(r["rank"] for r in peak.values()) == [1, 2]
    assert peak["billet.diameter_mm"]["rank"] == 1 and peak["billet.diameter_mm"]["src"] > 0
    # no lap in any sample: a constant response ranks nothing
    assert {r["rank"] for r in records if r["response"] == "laps"} == {0}
    write_sensitivities(records, tmp_path / "s" / "sensitivity.csv")
    paths = write_figures(study, tmp_path / "s", records)
    assert [p.name for p in paths] == ["scatter_matrix.png", "main_effects.png", "ranking.png"]
    assert all(p.read_bytes()[:4] == b"\x89PNG" for p in paths)


def test_progress_lines_count_failures_and_time_left():
    """Off a terminal: a line per sample with done/total, failures and seconds left (the
    first call, the samples a resumed study found, prints nothing)."""
    import io

    from jaxform.cli import StudyProgress

    log = io.StringIO()
    p = StudyProgress(log)
    p(1, 4, 0)
    p(2, 4, 0)
    p(3, 4, 1)
    lines = log.getvalue().splitlines()
    assert [ln.split(",")[0] for ln in lines] == ["sample 2/4 done", "sample 3/4 done"]
    assert "1 failed" in lines[1] and "s left" in lines[1]


def test_cli_on_a_cluster_address_writes_the_same_table(finished, client, tmp_path, capsys):
    """jaxform study --cluster ADDRESS (the test's local scheduler, reached by its
    address): exit 0, the outputs listed, and the table equal to the local run's row by
    row (every column but wall time and worker; reference: the finished fixture)."""
    from jaxform.cli import main

    study, local = finished
    argv = ["study", SEED, "--out", str(tmp_path / "c"), "--cluster", client.scheduler.address]
    for s in SMALL + STUDY:
        argv += ["--set", s]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "done: 3 samples run (0 failed)" in out and "sensitivity.csv" in out
    by_id = lambda rows: {r["sample"]: r for r in rows}  # noqa: E731
    a, b = by_id(read_table(local / RESULTS)), by_id(read_table(tmp_path / "c" / RESULTS))
    assert a.keys() == b.keys()
    for i in a:
        for col in a[i]:
            if col not in ("wall_s", "worker"):
                assert a[i][col] == b[i][col], (i, col)


@pytest.mark.slow
def test_bench_study_quick_mode_writes_its_table(tmp_path):
    """experiments/bench_study.py --quick on 2 samples, the loop and 1 worker: a row per
    mode with a positive rate, and the scheduler overhead row (the benchmark runs)."""
    import csv

    bench = experiment("bench_study")
    import jax

    saved = os.environ.get("JAXFORM_CACHE_DIR")
    saved_dir = jax.config.jax_compilation_cache_dir
    try:
        bench.main(["--quick", "--samples", "2", "--out", str(tmp_path),
                    "--modes", "loop", "workers=1"])  # fmt: skip
    finally:  # the benchmark points the cache at an empty folder for its cold compiles
        os.environ["JAXFORM_CACHE_DIR"] = saved or ""
        if saved is None:
            del os.environ["JAXFORM_CACHE_DIR"]
        jax.config.update("jax_compilation_cache_dir", saved_dir)
    rows = list(csv.DictReader(open(tmp_path / "bench_study.csv")))
    assert [r["mode"] for r in rows] == ["loop", "workers=1", "scheduler_overhead"]
    assert all(float(r["per_min"]) > 0 for r in rows[:2]) and float(rows[2]["wall_s"]) > 0
