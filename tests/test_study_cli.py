"""jaxform study refuses bad input up front: one line naming the key or flag and what is
allowed, exit status 2, before a worker starts or anything compiles (tests/cli_harness.py
stubs every entry point that would compile; the local cluster is stubbed too)."""

from pathlib import Path
from unittest import mock

import pytest
from cli_harness import assert_refused

import jaxform.study.engine as engine

SEED = str(Path(__file__).resolve().parents[1] / "configs" / "upsetting_seed.toml")
SPEED = '"die.speed_mm_s = uniform(0.05, 0.1)"'


def _argv(tmp_path, *sets, extra=()):
    argv = ["study", SEED, "--out", str(tmp_path / "study")]
    for s in sets:
        argv += ["--set", s]
    return argv + list(extra)


@pytest.fixture(autouse=True)
def no_cluster():
    """A study that got past its checks would start a local cluster: refuse instead."""

    def refuse(*args, **kwargs):
        raise AssertionError("bad input reached the cluster")

    with mock.patch.object(engine, "LocalCluster", refuse, create=True):
        with mock.patch("distributed.LocalCluster", refuse):
            yield


@pytest.mark.parametrize(
    "sets, needle",
    [
        (['study.inputs=["die.nope = uniform(0, 1)"]'], "unknown key die.nope"),
        (['study.inputs=["friction.model = levels(1, 2)"]'], "friction.model is not a numeric"),
        (['study.inputs=["friction.m = uniform(0.5, 1.5)"]'], "friction.m's allowed range [0, 1]"),
        (["study.inputs=[]"], "study.inputs = []: empty plan"),
        ([f"study.inputs=[{SPEED}]", "study.samples=0"], "study.samples = 0: must lie in"),
        ([f"study.inputs=[{SPEED}]", 'study.plan="sobol"', "study.samples=12"], "power of 2"),
        ([f"study.inputs=[{SPEED}]", 'study.plan="grid"'], "study.plan = 'grid'"),
        ([f"study.inputs=[{SPEED}]", 'study.responses=["force_N:mean"]'], "study.responses[0]"),
        ([f"study.inputs=[{SPEED}, {SPEED}]"], "die.speed_mm_s is given twice"),
        # a normal whose draws leave the key's range: refused with the value drawn
        (['study.inputs=["friction.m = normal(0.5, 1)"]'], "draws"),
        # a sample whose scene is refused (the step count): the sample and the key named
        (['study.inputs=["die.speed_mm_s = uniform(1e-7, 2e-7)"]', "study.samples=2"],
         "study sample 0 (die.speed_mm_s="),
        # exact gradients: inputs and responses the differentiable run has, no remeshing
        (['study.inputs=["billet.diameter_mm = uniform(4, 6)"]', "study.gradients=true"],
         "billet.diameter_mm is not an input of a design group"),
        ([f"study.inputs=[{SPEED}]", "study.gradients=true", 'study.responses=["laps"]'],
         "response 'laps' is not on the differentiable run"),
        (['study.inputs=["friction.m = uniform(0.1, 0.3)"]', "study.gradients=true"],
         "friction.m needs friction.model = 'shear'"),
        ([f"study.inputs=[{SPEED}]", "study.gradients=true", "remesh.every_steps=5"],
         "the scene remeshes"),
        ([f"study.inputs=[{SPEED}]", "study.batch=4", "remesh.every_steps=5"],
         "study.batch = 4: the scene remeshes"),
    ],
)  # fmt: skip
def test_bad_study_input_is_one_line_exit_2(tmp_path, sets, needle):
    assert_refused(_argv(tmp_path, *sets), needle)
    assert not (tmp_path / "study" / "results.csv").exists()


@pytest.mark.parametrize(
    "address", ["nonsense", "tcp://host", "tcp://host:99999", "http://10.0.0.1:8786"]
)
def test_a_malformed_cluster_address_is_refused(tmp_path, address):
    line = assert_refused(_argv(tmp_path, f"study.inputs=[{SPEED}]", extra=["--cluster", address]),
                          "--cluster")  # fmt: skip
    assert "tcp://HOST:PORT" in line


def test_a_cluster_that_does_not_answer_is_refused(tmp_path):
    """Reference: nothing listens on 127.0.0.1 port 9 (discard) here; the client gives up
    after CONNECT_TIMEOUT_S (lowered to 1 s) and the study stops before writing a file."""
    with mock.patch.object(engine, "CONNECT_TIMEOUT_S", 1.0):
        assert_refused(
            _argv(tmp_path, f"study.inputs=[{SPEED}]", extra=["--cluster", "tcp://127.0.0.1:9"]),
            "no Dask scheduler answered",
        )
    assert not (tmp_path / "study" / "plan.csv").exists()


def test_workers_flag_and_existing_table(tmp_path):
    assert_refused(_argv(tmp_path, f"study.inputs=[{SPEED}]", extra=["--workers", "-1"]),
                   "--workers = -1")  # fmt: skip
    out = tmp_path / "study"
    out.mkdir()
    (out / "results.csv").write_text("sample\n0\n")
    assert_refused(_argv(tmp_path, f"study.inputs=[{SPEED}]"), "give --resume")


def test_resume_with_another_plan_is_refused(tmp_path):
    """A folder's plan.csv from seed 0; --resume with seed 1 would mix two plans."""
    from jaxform.study.engine import _write_plan
    from jaxform.study.spec import build_study

    out = tmp_path / "study"
    out.mkdir()
    _write_plan(build_study(SEED, [f"study.inputs=[{SPEED}]", "study.seed=0"]), out / "plan.csv")
    assert_refused(_argv(tmp_path, f"study.inputs=[{SPEED}]", "study.seed=1",
                         extra=["--resume"]), "--resume: the plan")  # fmt: skip
