"""A script of experiments/ loaded as a module, so that a test checks its functions on
inputs whose answers are known."""

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def experiment(name: str):
    """experiments/<name>.py as a module."""
    spec = importlib.util.spec_from_file_location(name, ROOT / "experiments" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
