"""An installed jaxform (not the source tree) finds its material presets from any directory.

The presets are package data (pyproject.toml [tool.setuptools.package-data]) read with
importlib.resources.  The fast test lays the package out as setuptools' build_py does for
a wheel (the .py files and the declared package data, nothing else) and validates every
config in configs/ from another directory; the slow one builds and installs a real wheel.
"""

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PRESETS = sorted(p.stem for p in (ROOT / "jaxform" / "materials" / "data").glob("*.toml"))
CONFIGS = sorted(str(p) for p in (ROOT / "configs").glob("*.toml"))

# set every config up (mesh, material, die or load; nothing compiled), print the presets
# found and where jaxform lives
VALIDATE = """
import sys
import jaxform
jaxform.enable_x64()
from jaxform.materials.presets import available_presets
from jaxform.process import prepare
from jaxform.process_config import load_document, operations
for path in sys.argv[1:]:
    doc = load_document(path)
    if "process" in doc:  # a multi-stage process: its first operation's scene
        ops = operations(doc)
        prepare(ops)
        jaxform.build_scene(ops[0].config)
    else:
        jaxform.build_scene(jaxform.load_config(path))
print(",".join(available_presets()))
print(jaxform.__file__)
"""


def short_run(config: str) -> list[str]:
    """Overrides that make a shipped config a short run (2 x 2 mesh, a few steps)."""
    small = ["--set", "mesh.nr=2", "--set", "mesh.nz=2", "--set", "output.plots=false"]
    if "[[process.operation]]" in Path(config).read_text():
        # a process's dies are placed for the part its mesh forms (a 2 x 2 blocked part
        # stands higher than the finisher's start): run on its own mesh (8 x 5, ~200 s CPU)
        return ["--set", "output.plots=false", "--set", "output.fields=false"]
    if "membrane" in Path(config).read_text():
        return [*small, "--set", "time.dt_s=0.5", "--set", "load.ramp_time_s=1.0"]
    return [*small, "--set", "die.reduction=0.02"]


def _env_without_source_tree() -> dict:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["JAX_PLATFORMS"] = "cpu"
    return env


def _copy_source(tmp: Path) -> Path:
    """What a build reads (the package and its metadata), copied so that a build writes
    nothing into the repository."""
    src = tmp / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, src / name)
    shutil.copytree(ROOT / "jaxform", src / "jaxform", ignore=shutil.ignore_patterns("__pycache__"))
    return src


def _validate(python: str, cwd: Path, env: dict) -> list[str]:
    out = subprocess.run(
        [python, "-c", VALIDATE, *CONFIGS],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout.split()


def test_presets_are_package_data_and_load_without_the_source_tree(tmp_path):
    """Reference: the preset files in the repository.  The build layout must hold every
    one of them, and jaxform imported from it (not from the source tree, whose configs/
    folder it cannot see) must load every config's material."""
    src = _copy_source(tmp_path)
    lib = tmp_path / "lib"
    build = subprocess.run(
        [
            sys.executable,
            "-c",
            "import setuptools; setuptools.setup()",
            "-q",
            "build_py",
            "--build-lib",
            str(lib),
        ],
        cwd=src,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert build.returncode == 0, build.stderr[-2000:]
    shipped = sorted(p.stem for p in (lib / "jaxform").rglob("*.toml"))
    assert PRESETS and shipped == PRESETS
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    env = _env_without_source_tree()
    env["PYTHONPATH"] = str(lib)
    presets, where = _validate(sys.executable, elsewhere, env)
    assert presets.split(",") == PRESETS
    assert Path(where).resolve().is_relative_to(lib.resolve())


@pytest.mark.slow
def test_installed_wheel_runs_from_another_directory(tmp_path):
    """`pip wheel` + install into a fresh venv; the installed `jaxform` sets up and runs
    every config from another directory (short runs) and names the shipped presets in
    its error line."""
    env = _env_without_source_tree()
    pip = [sys.executable, "-m", "pip"]
    subprocess.run(
        [
            *pip,
            "wheel",
            "--no-deps",
            "-q",
            "-w",
            str(tmp_path / "dist"),
            str(_copy_source(tmp_path)),
        ],
        check=True,
        env=env,
        cwd=tmp_path,
        timeout=600,
    )
    wheel = next((tmp_path / "dist").glob("jaxform-*.whl"))
    names = zipfile.ZipFile(wheel).namelist()
    assert sorted(Path(n).stem for n in names if n.endswith(".toml")) == PRESETS
    venv = tmp_path / "venv"
    subprocess.run(
        [sys.executable, "-m", "venv", "--system-site-packages", str(venv)], check=True, timeout=300
    )
    python = str(venv / "bin" / "python")
    subprocess.run(
        [python, "-m", "pip", "install", "--no-deps", "-q", str(wheel)],
        check=True,
        env=env,
        timeout=300,
    )
    presets, where = _validate(python, tmp_path, env)
    assert presets.split(",") == PRESETS
    assert Path(where).resolve().is_relative_to(venv.resolve())
    bad = subprocess.run(
        [str(venv / "bin" / "jaxform"), "run", CONFIGS[0], "--set", "material.preset=steel"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1, bad.stderr
    assert all(p in bad.stderr for p in PRESETS), bad.stderr
    for config in CONFIGS:
        out = tmp_path / "runs" / Path(config).stem
        done = subprocess.run(
            [str(venv / "bin" / "jaxform"), "run", config, "--out", str(out), *short_run(config)],
            cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600, check=False,
        )  # fmt: skip
        assert done.returncode == 0, (config, done.stderr[-2000:])
        assert (out / "history.csv").is_file() and (out / "config.toml").is_file()
