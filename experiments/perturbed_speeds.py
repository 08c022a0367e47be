"""How many runs of a scene reach the end when its die speed moves by a hair.

A run whose contact and friction path depends on the rounding of one machine passes on
that machine and fails on another (CI's). Changing the die speed by up to ``--spread``
(relative) changes which step sizes the run takes, as another machine's rounding does; a
robust scene reaches the end on every one.

    python experiments/perturbed_speeds.py tests/test_friction_per_die.py:RING --runs 20 \
        --seed 2 --set "side_die.profile_mm=[[7.0, 0.0], [7.0, 5.0]]" \
        --set side_die.friction.model=shear --set side_die.friction.m=0.5 \
        [--set solver.max_quality_drop=0 ...]
    python experiments/perturbed_speeds.py configs/closed_die.toml --runs 3

The scene is a config file or ``module.py:NAME`` (a config dict of that module).  Prints
one line a run (the speed, the end or the failure's line) and the count."""

from __future__ import annotations

import argparse
import importlib.util
import sys
from pathlib import Path

import numpy as np

import jaxform
from jaxform.config import load_config
from jaxform.scenes import build_scene
from jaxform.simulation import SimulationError, simulate


def _scene_source(spec: str):
    """The config source of ``spec``: a path, or the dict ``NAME`` of ``file.py:NAME``."""
    if ":" not in spec:
        return spec
    path, name = spec.split(":")
    sys.path.insert(0, str(Path(path).parent))
    mod_spec = importlib.util.spec_from_file_location(Path(path).stem, path)
    mod = importlib.util.module_from_spec(mod_spec)
    sys.modules[mod_spec.name] = mod  # its dataclasses look their module up
    mod_spec.loader.exec_module(mod)
    return getattr(mod, name)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene")
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--spread", type=float, default=1e-3, help="relative speed change, at most")
    ap.add_argument("--set", action="append", default=[], help="a config override key=value")
    args = ap.parse_args(argv)
    jaxform.enable_x64()
    jaxform.enable_compilation_cache()
    source = _scene_source(args.scene)
    base = load_config(source, args.set)
    speed = float(base["die"]["speed_mm_s"])
    rng = np.random.default_rng(args.seed)
    reached = 0
    for k in range(args.runs):
        v = speed * (1.0 + rng.uniform(-args.spread, args.spread))
        cfg = load_config(source, (*args.set, "output.plots=false", "output.fields=false",
                                   f"die.speed_mm_s={v!r}"))  # fmt: skip
        try:
            h = simulate(build_scene(cfg)).history
        except SimulationError as err:
            print(f"{k:3d} speed {v:.10g} mm/s: stopped: {err}", flush=True)
            continue
        reached += 1
        print(f"{k:3d} speed {v:.10g} mm/s: the end, {len(h['time_s']) - 1} steps, "
              f"force {h['force_N'][-1]:.6g} N, {int(np.sum(h['cutbacks']))} cutbacks",
              flush=True)  # fmt: skip
    print(f"{reached} of {args.runs} reach the end")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
