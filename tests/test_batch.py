"""Batched designs (jaxform.batch): one compiled program for a batch of designs.

References: the same design problem run one design at a time (DesignProblem.value_and_grad,
its own compiled program), to 1e-10 relative; and the batch sharded over 2 host CPU devices
(a subprocess started with XLA_FLAGS=--xla_force_host_platform_device_count=2, because the
device count is fixed when JAX initializes; 15 designs, padded to 16: 8 a device, the size
at which vmapped slices hung on a 2-core machine) against the unsharded batch: the
sharded forward program (values, forces, final state; the gradient program is sharded by
the same code and would double the test's compile time).  The subprocess is started
before the first compile here so that it compiles on the other core meanwhile.
"""

import os
import subprocess
import sys
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from batch_case import MUS, designs, problem

from jaxform.batch import BatchProblem
from jaxform.gradients import GradientRunError

HERE = Path(__file__).parent


@pytest.fixture(scope="module")
def sharded(tmp_path_factory):
    """The sharded run in a subprocess: started now, collected by the test that needs it."""
    out = tmp_path_factory.mktemp("sharded") / "sharded.npz"
    env = dict(
        os.environ,
        XLA_FLAGS="--xla_force_host_platform_device_count=2",
        PYTHONPATH=os.pathsep.join([str(HERE.parent), os.environ.get("PYTHONPATH", "")]),
    )
    proc = subprocess.Popen(
        [sys.executable, str(HERE / "batch_case.py"), str(out)],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    yield proc, out
    if proc.poll() is None:
        proc.kill()


@cache
def case():
    return problem()


@cache
def batched():
    val, grad, traj = BatchProblem(case()).value_and_grad(designs())
    return np.asarray(val), np.asarray(grad["friction"]), traj


def rel(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


def test_batch_equals_single_runs(sharded):  # requests `sharded` to start it early
    val, grad, traj = batched()
    assert val.shape == (len(MUS),) and grad.shape == (len(MUS), 1)
    pb = case()
    d = designs()
    for i in range(len(MUS)):
        v1, g1, t1 = pb.value_and_grad({"friction": d["friction"][i]})
        assert rel(val[i], v1) <= 1e-10
        assert rel(grad[i], g1["friction"]) <= 1e-10
        assert rel(traj.force_N[i], t1.force_N) <= 1e-10
        assert rel(traj.x[i], t1.x) <= 1e-10
        assert np.array_equal(np.asarray(traj.iterations[i]), np.asarray(t1.iterations))
    # the designs differ: friction changes the force and its gradient is not zero
    assert np.all(np.diff(val) > 0) and np.all(grad > 0)


def test_sharded_batch_equals_unsharded(sharded):
    proc, out = sharded
    log, _ = proc.communicate(timeout=600)
    assert proc.returncode == 0, log
    r = np.load(out)
    assert int(r["devices"]) == 2 and int(r["placed_devices"]) == 2
    val, grad, traj = batched()
    assert len(r["value"]) == 15  # trimmed back from 16
    n = 3  # the designs both batches hold (MUS[:3])
    assert rel(r["value"][:n], val[:n]) <= 1e-10
    assert rel(r["force"][:n], np.asarray(traj.force_N)[:n]) <= 1e-10
    assert rel(r["x"][:n], np.asarray(traj.x)[:n]) <= 1e-10
    assert np.all(np.isfinite(r["value"]))


def test_failed_design_is_named():
    from jaxform.batch import check_batch
    from jaxform.gradients import Trajectory

    val, grad, traj = batched()
    codes = np.zeros_like(np.asarray(traj.codes))
    codes[2, 4] = 1
    bad = Trajectory(**{**{k: getattr(traj, k) for k in traj.__dataclass_fields__}, "codes": codes})
    with pytest.raises(GradientRunError, match="design 2, step 5"):
        check_batch(bad)
