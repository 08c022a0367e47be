"""The tonnage convergence benchmark's reading of a run (experiments/tonnage_convergence.py):
its dips and its spread are what issue 38 item 4 is judged by, so they are checked on a
history whose numbers are known."""

import csv
from pathlib import Path

import pytest
from experiment_loader import experiment


@pytest.fixture(scope="module")
def bench():
    return experiment("tonnage_convergence")


def _history(folder: Path, rows):
    cols = ["stroke_mm", "force_N", "newton_iterations", "remeshed", "die_fill", "flash_volume_mm3"]
    with open(folder / "history.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        w.writerows(rows)


def test_dips_and_summary_of_a_known_history(bench, tmp_path):
    # remeshes at 1.0 mm (next step 950 N against 1000: -5 %) and at 4.5 mm (next 1980
    # against 1800: +10 %, a rise, so the flash's worst dip is the -2 % one at 4.6 mm)
    rows = [
        (0.0, 0.0, 0, 0, 0.5, 0.0),
        (1.0, 1000.0, 4, 1200, 0.6, 0.0),
        (1.5, 950.0, 6, 0, 0.7, 0.0),
        (4.5, 1800.0, 8, 1300, 0.95, 10.0),
        (4.6, 1980.0, 10, 1310, 0.99, 20.0),
        (4.7, 1940.4, 2, 0, 0.999, 30.0),
    ]
    _history(tmp_path, rows)
    got = bench.dips(list(csv.DictReader(open(tmp_path / "history.csv"))))
    assert [s for s, _ in got] == [1.0, 4.5, 4.6]
    assert [d for _, d in got] == pytest.approx([-5.0, 10.0, -2.0])
    s = bench.summary(tmp_path, flash_mm=4.25)
    assert s["end_force_N"] == 1940.4 and s["end_stroke_mm"] == 4.7
    assert s["remeshes"] == 3 and s["steps"] == 5
    assert s["newton_per_step"] == pytest.approx(6.0)  # (4 + 6 + 8 + 10 + 2) / 5
    assert s["worst_dip_before_pct"] == pytest.approx(-5.0)
    assert s["worst_dip_flash_pct"] == pytest.approx(-2.0)
    assert s["die_fill"] == 0.999 and s["flash_volume_mm3"] == 30.0


def test_table_gives_the_spread_of_the_finished_runs_only(bench):
    base = dict(remeshes=1, steps=10, newton_per_step=5.0, worst_dip_before_pct=-1.0,
                worst_dip_flash_pct=-2.0, die_fill=0.999, flash_volume_mm3=1.0)  # fmt: skip
    rows = [
        dict(dt_s=1.0, element_size_mm=0.35, status="finished", end_stroke_mm=5.0,
             end_force_N=10000.0, **base),
        dict(dt_s=0.5, element_size_mm=0.35, status="finished", end_stroke_mm=5.0,
             end_force_N=10300.0, **base),
        dict(dt_s=0.25, element_size_mm=0.35, status="stopped: Newton", end_stroke_mm=4.0,
             end_force_N=5000.0, **base),
    ]  # fmt: skip
    text = bench.table(rows)
    assert "10000 - 10300 N, spread 3.0 %" in text
    assert "5000 (stopped at 4.00 mm)" in text
