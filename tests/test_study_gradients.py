"""Exact gradients of study responses (jaxform.study.gradients): each sample's gradient in
the keys' units equals a central difference of the same differentiable model.

Slow: the first sample compiles the forward and the gradient program of each response
(about 3 minutes on the 2-core CI machine for the 3 x 3 seed scene, two responses)."""

from pathlib import Path

import numpy as np
import pytest

from jaxform.study import gradients as G
from jaxform.study.engine import _task, evaluate_sample
from jaxform.study.spec import build_study

SEED = str(Path(__file__).resolve().parents[1] / "configs" / "upsetting_seed.toml")
SMALL = ["mesh.nr=3", "mesh.nz=3", "die.reduction=0.1", "time.dt_s=2.5", "output.fields=false",
         "output.plots=false", 'friction.model="shear"', "friction.m=0.3"]  # fmt: skip
STUDY = [
    'study.inputs=["friction.m = uniform(0.1, 0.5)", "die.speed_mm_s = uniform(0.06, 0.15)"]',
    "study.samples=2",
    'study.responses=["force_N:max", "friction_work_Nmm:end"]',
    "study.gradients=true",
]


@pytest.mark.slow
def test_sample_gradients_match_central_differences():
    """Reference: (J(x + h) - J(x - h)) / 2h of the same fixed-schedule model
    (problem.value) at the sample's values, h = 1e-5 x the value; tolerance 1e-6 relative
    (measured: agreement to ~1e-8).  The row's gradient columns are these gradients."""
    sets = SMALL + STUDY
    study = build_study(SEED, sets)
    task = _task(study, SEED, sets, 1)
    row = evaluate_sample(task)
    assert row["status"] == "ok" and row["message"] == "", row
    values = dict(zip(task.inputs, task.values))
    for r in study.responses:
        problem = G._problem(SEED, task.base, task.inputs, r)
        for k in task.inputs:
            h = 1e-5 * values[k]
            J = []
            for sign in (1.0, -1.0):
                moved = dict(values, **{k: values[k] + sign * h})
                J.append(float(problem.value(G.design_point(problem, moved)[0])[0]))
            fd = (J[0] - J[1]) / (2 * h)
            np.testing.assert_allclose(row[f"d_{r.name}/d_{k}"], fd, rtol=1e-6)


@pytest.mark.slow
def test_batched_rows_equal_the_unbatched_model():
    """study.batch = 4 with 3 samples (one chunk, padded): each row's responses equal
    problem.value of the same design point (the unbatched program of the same
    fixed-schedule model); tolerance 1e-10 relative (measured 1e-14)."""
    from jaxform.study.batched import BatchTask, evaluate_batch

    sets = SMALL + [*STUDY[:3], "study.samples=3", "study.batch=4"]
    study = build_study(SEED, sets)
    keys = tuple(i.key for i in study.inputs)
    values = tuple(tuple(map(float, v)) for v in study.values)
    rows = evaluate_batch(BatchTask((0, 1, 2), 4, SEED, tuple(sets), keys, values,
                                    study.responses))  # fmt: skip
    assert [r["status"] for r in rows] == ["ok"] * 3, rows
    for r in study.responses:
        problem = G._problem(SEED, tuple(sets), keys, r)
        for b, row in enumerate(rows):
            design, _ = G.design_point(problem, dict(zip(keys, values[b])))
            np.testing.assert_allclose(row[r.name], float(problem.value(design)[0]), rtol=1e-10)


@pytest.mark.slow
def test_thermal_gradients_in_kelvin_match_central_differences():
    """The coupled hot upsetting scene, coarse (3 x 3, 10 % reduction): the billet and die
    temperature gradients (per K: the thermal group's variable is (T - T0) / 100 K) and the
    ram speed's (per mm/s), against central differences of the same model, h = 1e-4 of the
    value; tolerance 1e-5 relative."""
    hot = str(Path(SEED).parent / "hot_upsetting.toml")
    sets = ["mesh.nr=3", "mesh.nz=3", "die.reduction=0.1", "time.dt_s=0.05",
            "output.fields=false", "output.plots=false",
            'study.inputs=["thermal.billet_temperature_K = uniform(623, 723)", '
            '"thermal.die_temperature_K = uniform(423, 573)", '
            '"die.speed_mm_s = uniform(5, 10)"]',
            "study.samples=1", 'study.responses=["force_N:max"]',
            "study.gradients=true"]  # fmt: skip
    study = build_study(hot, sets)
    task = _task(study, hot, sets, 0)
    row = evaluate_sample(task)
    assert row["status"] == "ok" and row["message"] == "", row
    values = dict(zip(task.inputs, task.values))
    problem = G._problem(hot, task.base, task.inputs, study.responses[0])
    for k in task.inputs:
        h = 1e-4 * values[k]
        J = []
        for sign in (1.0, -1.0):
            moved = dict(values, **{k: values[k] + sign * h})
            J.append(float(problem.value(G.design_point(problem, moved)[0])[0]))
        np.testing.assert_allclose(row[f"d_force_N_max/d_{k}"], (J[0] - J[1]) / (2 * h), rtol=1e-5)


@pytest.mark.slow
def test_batched_gradients_equal_the_single_samples():
    """study.batch = 2 with gradients: each row's gradient columns equal the unbatched
    evaluate_sample's (the same fixed-schedule model, one design at a time); tolerance
    1e-9 relative."""
    from jaxform.study.batched import BatchTask, evaluate_batch

    sets = SMALL + [*STUDY, "study.batch=2"]
    study = build_study(SEED, sets)
    keys = tuple(i.key for i in study.inputs)
    values = tuple(tuple(map(float, v)) for v in study.values)
    rows = evaluate_batch(BatchTask((0, 1), 2, SEED, tuple(sets), keys, values,
                                    study.responses, gradients=True))  # fmt: skip
    for b, row in enumerate(rows):
        single = evaluate_sample(_task(study, SEED, sets, b))
        names = [f"d_{r.name}/d_{k}" for r in study.responses for k in keys]
        assert row["status"] == "ok" and all(np.isfinite(row[n]) for n in names), row
        for n in names:
            np.testing.assert_allclose(row[n], single[n], rtol=1e-9)
