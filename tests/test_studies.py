"""Studies (issue 6, items 2-3): the stability map and the speed-accuracy study, quick modes.

Both scripts run once each, in-process, into a temporary directory (``studies`` fixture);
their quick modes share the compiled program of the friction scene (q1p0, 5 x 5, line
search on), so the file costs four compilations on 2 cores.  The helpers (Richardson
extrapolation, Pareto front, step cap) are checked against cases with known answers.
"""

import csv
import math
from pathlib import Path

import numpy as np
import pytest
from experiment_loader import experiment

from jaxform.config import load_config

ROOT = Path(__file__).resolve().parents[1]


stability = experiment("stability_map")
speed = experiment("speed_accuracy")


@pytest.fixture(scope="module")
def studies(tmp_path_factory):
    out = tmp_path_factory.mktemp("studies")
    return out, {
        "stability": stability.main(["--quick", "--out", str(out)]),
        "speed": speed.main(["--quick", "--out", str(out)]),
    }


def _csv_rows(path: Path) -> list[dict]:
    with open(path, newline="") as fh:
        return [r for r in csv.DictReader(fh) if not r[next(iter(r))].startswith("#")]


# ---------------------------------------------------------------------------------------
# helpers with known answers (no simulation)


def test_richardson_recovers_a_power_law():
    """u(h) = u* + c h^p with p = 1.5 on h = 1, 1/2, 1/4: the extrapolation is exact and
    the observed order is p; a sequence that changes direction is flagged not monotone."""
    exact = np.array([2.0, -1.0])
    vals = [exact + np.array([0.3, 0.1]) * h**1.5 for h in (1.0, 0.5, 0.25)]
    ext, p, mono = speed.richardson(*vals)
    assert mono and abs(p - 1.5) < 1e-12
    np.testing.assert_allclose(ext, exact, atol=1e-12)
    _, p, mono = speed.richardson(np.array([1.0]), np.array([2.0]), np.array([1.5]))
    assert not mono and math.isnan(p)


def test_pareto_front_drops_dominated_runs():
    rows = [
        dict(wall_s=1.0, e=0.1),
        dict(wall_s=2.0, e=0.2),
        dict(wall_s=3.0, e=0.01),
        dict(wall_s=0.5, e=0.5),
    ]
    assert [r["wall_s"] for r in speed.pareto(rows, "e")] == [0.5, 1.0, 3.0]


def test_small_steps_cap_the_stroke():
    """200 steps of 0.01 s at 0.01 /s nominal strain rate: 2 % reduction; dt = 1 s: the
    configured 56.3 %."""
    cfg = load_config(ROOT / "configs" / "upsetting_seed.toml")
    assert stability.capped_reduction(cfg, 0.01, 200) == pytest.approx(0.02)
    assert stability.capped_reduction(cfg, 1.0, 200) == pytest.approx(0.563)


# ---------------------------------------------------------------------------------------
# the quick runs


def test_stability_quick_writes_map(studies):
    """CSV with the documented columns, one row per (line search, dt); at least one run
    converged to the end without a failure message, and a failed run names its cause and
    stopped short of the end; the PNG is written."""
    out, res = studies
    assert (out / "stability_map.png").stat().st_size > 10_000
    rows = _csv_rows(out / "stability_map.csv")
    assert tuple(rows[0]) == stability.COLUMNS
    assert len(rows) == 4 and {r["line_search"] for r in rows} == {"True", "False"}
    done = [r for r in rows if r["status"] == "converged"]
    assert done, rows
    for r in done:
        assert r["failure"] == ""
        assert float(r["reached_stroke_mm"]) == pytest.approx(float(r["end_stroke_mm"]), rel=1e-9)
        assert float(r["mean_newton_per_step"]) >= 1.0
    for r in rows:
        if r["status"] == "failed":
            assert "failed after" in r["failure"]
            assert float(r["reached_stroke_mm"]) < float(r["end_stroke_mm"])
    # the config's dt = 1 s converges with the configured cutbacks and line search
    assert any(r["line_search"] == "True" and float(r["dt_s"]) == 1.0 for r in done)


def test_speed_accuracy_error_falls_with_the_mesh(studies):
    """Friction scene, q1p0, dt = 1 s: the force-stroke error against the mesh
    extrapolation falls from 5x5 to 10x10 to 20x20 (measured 6.3 %, 2.9 %, 1.0 %), and the
    coarsest is off by more than 2 % (the study would be empty if the reference were one
    of the runs)."""
    out, res = studies
    assert (out / "speed_accuracy.png").stat().st_size > 10_000
    rows = [r for r in _csv_rows(out / "speed_accuracy.csv") if r["mesh"] != "reference"]
    assert tuple(_csv_rows(out / "speed_accuracy.csv")[0]) == speed.COLUMNS
    err = {r["mesh"]: float(r["force_error"]) for r in rows}
    assert err["5x5"] > err["10x10"] > err["20x20"], err
    assert err["5x5"] > 0.02, err
    assert all(float(r["wall_s"]) > 0 for r in rows)
    assert any("extrapolated" in n for n in res["speed"]["notes"])
    picks = {c["target"]: c["run"] for c in res["speed"]["choices"]}
    assert set(picks) == set(speed.TARGETS)
