"""Exact gradients of a study's responses in its inputs, at each sample.

The existing design machinery (:mod:`jaxform.design`) differentiates a run over a fixed
step schedule through the implicit-function theorem.  A worker builds, once per base scene
and response, the design problem of the *base* scene (the config with its ``--set``
overrides, without the sample's values) whose design groups hold the study's inputs
(friction, ram speed, thermal inputs) and whose objective is the response read from the
differentiable trajectory; every sample is then a design point of that problem, so the
compiled program serves all samples (the ram speed scales the schedule's times: the step
count stays).  The gradient is converted from the groups' scaled variables to the keys'
units (per mm/s, per K, ...).

What it is the gradient of: the response of the run over the base scene's schedule (its
forward run's steps, scaled in time by the sample's speed), which is the differentiable
model of the sample; the table's response values come from the sample's own adaptive run
(:func:`jaxform.driver.run`), and differ from that model's by the time discretization.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

from jaxform.study.spec import GRADIENT_KEYS

_PROBLEMS: dict = {}  # (config, base overrides, inputs, response) -> DesignProblem


@dataclass(frozen=True, eq=False)
class ResponseObjective:
    """A study response of the differentiable trajectory: a column reduced at the end,
    maximum or minimum (``max_temperature_K``/``min_temperature_K``: the hottest and
    coldest node of each row)."""

    column: str
    reducer: str
    unit = "-"

    def __call__(self, traj, inputs):
        if self.column in ("max_temperature_K", "min_temperature_K"):
            pick = jnp.max if self.column.startswith("max") else jnp.min
            col = pick(traj.temperature_K, axis=1)
        else:
            col = getattr(traj, self.column)
        if self.reducer == "max":
            return jnp.max(col)
        if self.reducer == "min":
            return jnp.min(col)
        return col[-1]

    def __hash__(self):
        return id(self)


def _problem(config, base: tuple[str, ...], keys: tuple[str, ...], response):
    """The base scene's design problem for one response (built once per worker): the
    scene, its forward run and step schedule once for all responses, each response's
    problem that one with its own objective."""
    from dataclasses import replace

    from jaxform.cache import enable_compilation_cache
    from jaxform.config import load_config, typed
    from jaxform.design import build_problem
    from jaxform.scenes import build_scene

    base_key = (repr(config), base, keys)
    cache_key = (*base_key, response.text)
    if cache_key not in _PROBLEMS:
        objective = ResponseObjective(response.column, response.reducer)
        first = next((p for k, p in _PROBLEMS.items() if k[:3] == base_key), None)
        if first is None:
            thermal = [k.split(".")[1] for k in keys if GRADIENT_KEYS[k] == "thermal"]
            extra = [f"design.thermal_params={thermal!r}".replace("'", '"')] if thermal else []
            cfg = typed(load_config(config, [*base, *extra]))
            # a worker is a fresh process: its programs come from the persistent cache
            enable_compilation_cache(cfg.solver.compilation_cache_dir)
            groups = tuple(dict.fromkeys(GRADIENT_KEYS[k] for k in keys))
            first = build_problem(build_scene(cfg), groups=groups, objective=objective)
        _PROBLEMS[cache_key] = replace(first, objective=objective)
    return _PROBLEMS[cache_key]


def design_point(problem, values: dict[str, float]) -> tuple[dict, dict[str, float]]:
    """(the design of the sample's values, d variable / d key per input key).

    friction: the coefficients themselves (a die's not among the inputs keeps its
    configured value); speed: u = log(v / v0); thermal: temperatures
    u = (T - T0) / 100 K, the die conductance u = log(h / h0), Taylor-Quinney itself."""
    design, scale = dict(problem.start), {}
    for g in problem.groups:
        if g.name == "friction":  # a key may set several dies' coefficients (friction.m)
            design["friction"] = jnp.asarray([values.get(v.key, v.value0) for v in g.variables])
            scale.update({v.key: 1.0 for v in g.variables if v.key in values})
        elif g.name == "speed":
            v = values["die.speed_mm_s"]
            design["speed"] = jnp.asarray([np.log(v / g.speed0_mm_s)])
            scale["die.speed_mm_s"] = 1.0 / v
        elif g.name == "thermal":
            u = []
            for n, v0 in zip(g.names, g.start):
                v = values[f"thermal.{n}"]
                if n == "htc_die_W_m2K":
                    u.append(np.log(v / v0))
                    scale[f"thermal.{n}"] = 1.0 / v
                elif n == "taylor_quinney":
                    u.append(v)
                    scale[f"thermal.{n}"] = 1.0
                else:
                    u.append((v - v0) / g.KELVIN_PER_UNIT)
                    scale[f"thermal.{n}"] = 1.0 / g.KELVIN_PER_UNIT
            design["thermal"] = jnp.asarray(u)
    return design, scale


def physical_gradient(problem, grad: dict, scale: dict[str, float]) -> dict[str, float]:
    """d response / d key (the key's units) from the gradient in the design variables."""
    out = {}
    for g in problem.groups:
        gv = np.asarray(grad[g.name])
        if g.name == "friction":  # the chain rule over the dies one key sets
            for i, v in enumerate(g.variables):
                if v.key in scale:
                    out[v.key] = out.get(v.key, 0.0) + float(gv[i])
        elif g.name == "speed":
            out["die.speed_mm_s"] = float(gv[0])
        elif g.name == "thermal":
            out.update({f"thermal.{n}": float(gv[i]) for i, n in enumerate(g.names)})
    return {k: v * scale[k] for k, v in out.items()}


def response_gradients(task) -> dict[str, float]:
    """The table's gradient columns ``d_<response>/d_<key>`` of one sample."""
    values = dict(zip(task.inputs, task.values))
    out = {}
    for r in task.responses:
        problem = _problem(task.config, task.base, task.inputs, r)
        design, scale = design_point(problem, values)
        _, grad, _ = problem.value_and_grad(design)
        g = physical_gradient(problem, grad, scale)
        out.update({f"d_{r.name}/d_{k}": g[k] for k in task.inputs})
    return out
