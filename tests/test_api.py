"""The public API: ``import jaxform`` is cheap and inert, every exported name resolves and
is documented, the design entry points refuse scenes they cannot handle before compiling,
and the Python tutorial runs (with a finite-difference check of its gradient)."""

import importlib
import inspect
import runpy
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import jaxform
from jaxform.cli import main

ROOT = Path(__file__).resolve().parents[1]


def test_every_exported_name_resolves_and_is_documented():
    """Reference: the docstring convention of the entry points (Arguments and Returns)."""
    assert {
        "run",
        "load_config",
        "build_scene",
        "simulate",
        "trajectory",
        "build_problem",
        "optimize",
        "taylor_test",
        "enable_x64",
    } <= set(jaxform.__all__)
    for name in jaxform.__all__:
        obj = getattr(jaxform, name)
        assert callable(obj), name
        doc = inspect.getdoc(obj) or ""
        assert "Arguments" in doc and "Returns" in doc, name
    assert set(jaxform.__all__) == set(jaxform._EXPORTS)
    importlib.import_module("jaxform.simulation")
    assert inspect.isfunction(jaxform.simulate)
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        _ = jaxform.nothing


def test_import_is_inert():
    """``import jaxform`` loads neither JAX nor matplotlib and sets nothing; the first use
    of an entry point loads its module."""
    script = (
        "import sys, jaxform; print(sorted(m for m in ('jax', 'matplotlib', "
        "'jaxform.driver') if m in sys.modules)); jaxform.load_config; "
        "print('jaxform.config' in sys.modules, 'jax' in sys.modules)"
    )
    out = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=120, check=False
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split("\n")[:2] == ["[]", "True False"]


@pytest.mark.parametrize("command", ["taylor-test", "design"])
def test_design_commands_refuse_a_scene_without_a_die(command, capsys, monkeypatch, tmp_path):
    """Cook's membrane has no [die] or [friction]: one config-error line naming them and
    exit 2, before the design problem's forward run (schedule) would compile anything."""
    from jaxform.design import problem

    def compiles(*args, **kwargs):
        raise AssertionError("the design problem got as far as a forward run")

    monkeypatch.setattr(problem, "remeshed_schedule", compiles)
    argv = [command, str(ROOT / "configs" / "cooks_membrane.toml")]
    code = main(argv + (["--out", str(tmp_path / "out")] if command == "design" else []))
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    assert err.startswith("config error: ") and "[die] or [friction]" in err, err
    assert "[billet], [ring], [block]" in err
    assert not (tmp_path / "out").exists()


def test_tutorial_runs_and_its_gradient_is_right(capsys):
    """examples/tutorial.py as a user runs it.  References: Anand's flow stress at a fixed
    deformation resistance grows like asinh((rate/A)^m), and its saturation like
    (rate/A)^n, so doubling the ram speed raises the force by a factor in
    (1, 2^(m + n)] (m = 0.23348, n = 0.07049); the gradient of the forging work with
    respect to log s0 equals central differences of the same compiled program (h = 1e-4:
    truncation ~1e-8, Newton tolerance 1e-10 / h ~ 1e-6, so 1e-5 relative)."""
    ns = runpy.run_path(str(ROOT / "examples" / "tutorial.py"), run_name="__main__")
    printed = capsys.readouterr().out
    assert "d work / d log s0_MPa" in printed and "forging work" in printed
    ratio = ns["fast"].history["force_N"][-1] / ns["slow"].history["force_N"][-1]
    assert 1.0 < ratio <= 2.0 ** (0.23348 + 0.07049), ratio
    problem, grad = ns["problem"], np.asarray(ns["grad"]["material"])
    h = 1e-4
    step = np.zeros_like(grad)
    step[0] = h
    up = float(problem.value({"material": problem.start["material"] + step})[0])
    down = float(problem.value({"material": problem.start["material"] - step})[0])
    fd = (up - down) / (2 * h)
    assert grad[0] > 0 and abs(grad[0] - fd) <= 1e-5 * abs(fd), (grad[0], fd)


def test_design_names_are_the_functions_whichever_module_loads_first():
    """The lazy package exports (PEP 562) give the function ``optimize`` even after its
    module was loaded by name (a submodule named like an export would shadow it)."""
    import importlib

    importlib.import_module("jaxform.design.optimizers")
    from jaxform.design import OptimizerSettings, optimize, taylor_test

    assert callable(optimize) and callable(taylor_test)
    assert optimize.__name__ == "optimize" and OptimizerSettings.__name__ == "OptimizerSettings"


def test_process_design_tutorial_runs_quick(capsys, monkeypatch):
    """examples/process_design.py --quick (2 L-BFGS iterations of the two-blow process):
    the objective falls (by half at least: measured 13.3 -> 2.5); the designed.toml it
    writes runs (`jaxform.run`) to the design's finisher flash (relative 1e-6: the run
    and the design's replay agree to Newton's tolerance) and fill (1e-9); the files a
    design writes are there.  Reference: the design's own report."""
    monkeypatch.setattr(sys, "argv", ["process_design.py", "--quick"])
    ns = runpy.run_path(str(ROOT / "examples" / "process_design.py"), run_name="__main__")
    printed = capsys.readouterr().out
    assert "designed.toml: flash" in printed
    assert "the best design's own forward run: objective" in printed
    assert "they differ" not in printed  # its forward run is its replay's run here
    hist, report = ns["hist"], ns["report"]
    assert hist.objective[hist.best] <= 0.5 * hist.objective[0], hist.objective
    fin = ns["designed"]["finisher"]
    best_flash = float(report["flash_volume"]["best"])
    assert abs(fin["flash_volume_mm3"][-1] - best_flash) <= 1e-6 * best_flash
    assert abs((1.0 - fin["die_fill"][-1]) - float(report["die_fill"]["best"])) <= 1e-9
    for name in ("designed.toml", "die_profiles.csv", "die_profiles.png", "design_report.csv"):
        assert (ns["out"] / name).is_file(), name
