"""The naive-family sweep's reading of a process run (experiments/billet_volume_sweep.py):
the reference a blocker design is judged by (issue 39: 30 % less flash than the least-flash
naive run that fills) comes from these functions, so they are checked on files whose
numbers are known."""

import csv
from pathlib import Path

import pytest
from experiment_loader import experiment


@pytest.fixture(scope="module")
def sweep():
    return experiment("billet_volume_sweep")


def _csv(path: Path, cols, rows):
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        w.writerows(rows)


def test_the_finisher_is_the_last_operation_that_moved_a_die(sweep, tmp_path):
    # blocker, a dwell (steps, no stroke), finisher, trim (no steps)
    _csv(tmp_path / "operations.csv",
         ["operation", "start_s", "end_s", "steps", "peak_force_N", "stroke_mm", "trimmed_mm3"],
         [(1, 0, 0.3, 17, 4022.5, 3.4, 0), (2, 0.3, 2.3, 8, 0, 0, 0),
          (3, 2.3, 2.5, 41, 26102.7, 2.0, 0), (4, 2.5, 2.5, 0, 0, 2.0, 40.9)])  # fmt: skip
    _csv(tmp_path / "history.csv", ["operation", "die_fill", "flash_volume_mm3"],
         [(1, 0.2, 0), (3, 0.9, 10.0), (3, 0.9991, 40.1), (4, 0.9913, 0)])  # fmt: skip
    op, peaks = sweep.last_forming(tmp_path)
    assert op == 3 and peaks == [4022.5, 26102.7]
    end = sweep.end_of(tmp_path, op)
    assert float(end["die_fill"]) == 0.9991 and float(end["flash_volume_mm3"]) == 40.1


def test_least_flash_among_the_runs_that_fill(sweep):
    rows = [
        dict(scale=0.97, status="finished", die_fill=0.998, flash_volume_mm3=20.0),
        dict(scale=1.0, status="finished", die_fill=0.9992, flash_volume_mm3=40.0),
        dict(scale=1.03, status="finished", die_fill=0.9995, flash_volume_mm3=55.0),
        dict(scale=0.99, status="stopped"),
    ]
    assert sweep.least_flash_filling(rows, 0.999)["scale"] == 1.0
    assert sweep.least_flash_filling(rows, 0.9999) is None
