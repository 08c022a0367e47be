"""A study's set-up from a validated config: its inputs, plan and responses, checked before
anything runs (every refusal is one :class:`ConfigError` line naming the key and what is
allowed).  Imports no JAX.

An input is ``section.key = distribution(parameters)``; each sample of the plan becomes the
base scene with ``section.key=value`` overrides (the ``--set`` machinery of
:func:`jaxform.config.load_config`), so a sample is exactly ``jaxform run CONFIG --set ...``.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from jaxform.config import (
    FRICTION_COEFFICIENT,
    FRICTION_DIES,
    SCHEMA,
    die_friction,
    friction_dies,
    friction_keys,
    load_config,
)
from jaxform.errors import ConfigError
from jaxform.study import plans

DISTRIBUTIONS = {"uniform": 2, "normal": 2, "lognormal": 2, "levels": None}
REDUCERS = ("end", "max", "min")
# the shorthand responses and the history column (at the end) or count they stand for
SHORTHANDS = {"fill": "die_fill", "flash": "flash_volume_mm3"}
# the inputs with exact gradients: the design group that holds each
# the friction coefficients: [friction]'s and each die's own table's
_FRICTION_SECTIONS = ("friction", *(f"{d}.friction" for d in FRICTION_DIES))
GRADIENT_KEYS = {
    **{f"{sec}.{k}": "friction" for sec in _FRICTION_SECTIONS for k in ("m", "mu")},
    "die.speed_mm_s": "speed",
    "thermal.billet_temperature_K": "thermal",
    "thermal.die_temperature_K": "thermal",
    "thermal.htc_die_W_m2K": "thermal",
    "thermal.taylor_quinney": "thermal",
}
# the history columns the differentiable run carries (temperatures: hottest, coldest node)
GRADIENT_COLUMNS = ("force_N", "stroke_mm", "friction_work_Nmm", "time_s",
                    "max_temperature_K", "min_temperature_K")  # fmt: skip
_INPUT = re.compile(r"^\s*([A-Za-z_][\w.]*)\.([A-Za-z_]\w*)\s*=\s*([a-z]+)\s*\((.*)\)\s*$")


@dataclass(frozen=True)
class Input:
    """One input: a numeric config key and its distribution."""

    key: str  # section.key
    dist: str  # uniform | normal | lognormal | levels
    params: tuple[float, ...]
    integer: bool = False  # an int key: values rounded to the nearest integer

    def factorial_levels(self, n: int) -> np.ndarray:
        """The levels of a factorial plan: given levels, or n per distribution."""
        if self.dist == "levels":
            v = np.asarray(self.params, dtype=float)
        elif self.dist == "uniform":
            v = np.linspace(self.params[0], self.params[1], n)
        else:
            return self.from_unit((np.arange(n) + 0.5) / n)
        # an int key runs at the rounded value: the plan records what runs
        return np.rint(v) if self.integer else v

    def from_unit(self, u: np.ndarray) -> np.ndarray:
        """Values of this input at points u in [0, 1) of the unit interval (inverse CDF)."""
        v = plans.inverse_cdf(self.dist, self.params, np.asarray(u, dtype=float))
        return np.rint(v) if self.integer else v


@dataclass(frozen=True)
class Response:
    """One response: ``column`` reduced by ``reducer`` (end, max, min), or the lap count."""

    text: str  # as given (force_N:max, fill, laps)
    column: str  # history column ('' for laps)
    reducer: str  # end | max | min | count

    @property
    def name(self) -> str:
        """The table column."""
        return "laps" if self.reducer == "count" else f"{self.column}_{self.reducer}"


@dataclass(frozen=True)
class Study:
    """Inputs, responses, the sample matrix (samples x inputs) and the settings."""

    inputs: tuple[Input, ...]
    responses: tuple[Response, ...]
    values: np.ndarray  # (samples, inputs), in the keys' units
    gradients: bool
    retries: int
    batch: int = 0  # samples per batched task (0: one run per sample)

    def overrides(self, i: int) -> list[str]:
        """The ``section.key=value`` overrides of sample i (exact: repr of the float)."""
        return [_override(inp, v) for inp, v in zip(self.inputs, self.values[i])]

    @property
    def n(self) -> int:
        return len(self.values)


def _override(inp: Input, value: float) -> str:
    return f"{inp.key}={int(value)}" if inp.integer else f"{inp.key}={float(value)!r}"


def parse_input(text: str, where: str) -> Input:
    """``section.key = kind(a, b, ...)`` -> :class:`Input`, checked against the schema."""
    m = _INPUT.match(text)
    if not m:
        raise ConfigError(
            f"{where} = {text!r}: expected 'section.key = uniform(low, high)', "
            f"'normal(mean, std)', 'lognormal(mu, sigma)' or 'levels(a, b, ...)'"
        )
    section, name, dist, body = m.groups()
    key = f"{section}.{name}"
    if section not in SCHEMA or name not in SCHEMA[section]:
        raise ConfigError(f"{where}: unknown key {key}; any numeric config key (section.key)")
    field = SCHEMA[section][name]
    if not field.numeric or section == "study":
        raise ConfigError(
            f"{where}: {key} is not a numeric key ({field.kind}); a study varies float or int keys"
        )
    if dist not in DISTRIBUTIONS:
        raise ConfigError(f"{where}: {dist!r} is not a distribution; one of "
                          f"{', '.join(DISTRIBUTIONS)}")  # fmt: skip
    try:
        params = tuple(float(p) for p in body.split(",")) if body.strip() else ()
    except ValueError:
        raise ConfigError(f"{where} = {text!r}: the parameters must be numbers") from None
    want = DISTRIBUTIONS[dist]
    if (want is not None and len(params) != want) or not params:
        raise ConfigError(f"{where} = {text!r}: {dist} takes {want or 'one or more'} numbers")
    if not all(math.isfinite(p) for p in params):
        raise ConfigError(f"{where} = {text!r}: the parameters must be finite")
    inp = Input(key, dist, params, integer=field.integer)
    _check_range(inp, field, where)
    return inp


def _check_range(inp: Input, field, where: str) -> None:
    """The input's support within the key's allowed range (a uniform's ends, every level;
    normal and lognormal are checked sample by sample in :func:`_check_samples`)."""
    a = inp.params
    if inp.dist == "uniform" and not a[0] < a[1]:
        raise ConfigError(f"{where}: {inp.key} = uniform({a[0]:g}, {a[1]:g}): needs low < high")
    if inp.dist in ("normal", "lognormal") and not a[1] > 0:
        raise ConfigError(f"{where}: {inp.key} = {inp.dist}: the spread {a[1]:g} must be > 0")
    ends = a if inp.dist in ("uniform", "levels") else ()
    for v in ends:
        if not _within(field, v):
            raise ConfigError(
                f"{where}: {inp.key} = {inp.dist}({', '.join(f'{p:g}' for p in a)}): "
                f"{v:g} is outside {inp.key}'s allowed range {field.allowed()}"
            )


def _within(field, v: float) -> bool:
    lo_ok = field.low is None or (v >= field.low if field.low_inclusive else v > field.low)
    hi_ok = field.high is None or (v <= field.high if field.high_inclusive else v < field.high)
    return lo_ok and hi_ok


def parse_response(text: str, where: str) -> Response:
    if text in SHORTHANDS:
        return Response(text, SHORTHANDS[text], "end")
    if text == "laps":
        return Response(text, "", "count")
    column, colon, reducer = text.partition(":")
    if not colon or not re.fullmatch(r"[A-Za-z_]\w*", column) or reducer not in REDUCERS:
        raise ConfigError(
            f"{where} = {text!r}: expected 'column:end', 'column:max' or 'column:min' of a "
            f"history column, 'fill', 'flash' or 'laps'"
        )
    return Response(text, column, reducer)


def build_study(config, overrides=()) -> Study:
    """The study of a config (path or dict) with ``--set`` overrides: every input parsed,
    the plan drawn, every sample's config validated.  Raises ConfigError, one line."""
    doc = load_config(config, list(overrides))
    st = doc["study"]
    if not st["inputs"]:
        raise ConfigError(
            "study.inputs = []: empty plan: give at least one input, e.g. "
            "'friction.m = uniform(0.1, 0.5)'"
        )
    inputs = tuple(parse_input(t, f"study.inputs[{i}]") for i, t in enumerate(st["inputs"]))
    keys = [i.key for i in inputs]
    dup = next((k for k in keys if keys.count(k) > 1), None)
    if dup:
        raise ConfigError(f"study.inputs: {dup} is given twice")
    if not st["responses"]:
        raise ConfigError("study.responses = []: give at least one response, e.g. 'force_N:max'")
    responses = tuple(
        parse_response(t, f"study.responses[{i}]") for i, t in enumerate(st["responses"])
    )
    if st["gradients"]:
        _check_differentiable(doc, inputs, responses, "study.gradients = true")
    if st["batch"]:
        _check_differentiable(doc, inputs, responses, f"study.batch = {st['batch']}")
    values = draw(inputs, st["plan"], st["samples"], st["levels"], st["seed"])
    if len(values) == 0:
        raise ConfigError("study: empty plan (no sample)")
    study = Study(inputs, responses, values, st["gradients"], st["retries"], st["batch"])
    _check_samples(study, doc)  # the validated base: no file read per sample
    return study


def _check_differentiable(doc: dict, inputs, responses, what: str) -> None:
    """Gradients or batches (``what`` names the key): every input in a design group,
    every response on the differentiable run, no remeshing or rezoning (before anything
    runs)."""
    from jaxform.config import check_gradient_run, remesh_on

    bad = next((i.key for i in inputs if i.key not in GRADIENT_KEYS), None)
    if bad:
        raise ConfigError(
            f"{what}: {bad} is not an input of a design group; the inputs that are: "
            f"{', '.join(GRADIENT_KEYS)}"
        )
    bad = next((r.text for r in responses if r.column not in GRADIENT_COLUMNS), None)
    if bad:
        raise ConfigError(
            f"{what}: response {bad!r} is not on the differentiable run; the columns "
            f"that are: {', '.join(GRADIENT_COLUMNS)} (end, max or min)"
        )
    if remesh_on(doc["remesh"]):
        raise ConfigError(
            f"{what}: the scene remeshes ([remesh] triggers on): remeshing scenes run "
            f"one sample per task (study.gradients = false, study.batch = 0)"
        )
    used = friction_keys(doc) if "die" in doc else set()
    for i in inputs:
        if GRADIENT_KEYS[i.key] == "friction" and i.key not in used:
            section, _, coefficient = i.key.rpartition(".")
            want = next(m for m, c in FRICTION_COEFFICIENT.items() if c == coefficient)
            die = section.removesuffix(".friction")
            if die != "friction" and die not in friction_dies(doc):
                raise ConfigError(f"{what}: {i.key}: the scene has no {die}")
            model = (doc["friction"]["model"] if die == "friction" or "die" not in doc
                     else die_friction(doc, die)["model"])  # fmt: skip
            raise ConfigError(f"{what}: {i.key} needs {section}.model = {want!r} (it is {model!r})")
    check_gradient_run(doc, list(dict.fromkeys(GRADIENT_KEYS[i.key] for i in inputs)),
                       what.split(" ")[0])  # fmt: skip


def draw(inputs, plan: str, samples: int, levels: int, seed: int) -> np.ndarray:
    """The sample matrix (samples x inputs) of a plan."""
    if plan == "factorial":
        n = math.prod(len(i.factorial_levels(levels)) for i in inputs)
        if n > 100_000:
            raise ConfigError(
                f"study.plan = 'factorial': {n} samples, at most 100000: fewer inputs or "
                f"study.levels"
            )
        return plans.full_factorial([i.factorial_levels(levels) for i in inputs])
    if plan == "sobol" and samples & (samples - 1):
        raise ConfigError(
            f"study.samples = {samples}: a Sobol plan takes a power of 2 (e.g. "
            f"{1 << (samples.bit_length() - 1)} or {1 << samples.bit_length()}): its balance "
            f"holds only there"
        )
    unit = plans.unit_plan(plan, samples, len(inputs), seed)
    return np.stack([inp.from_unit(unit[:, j]) for j, inp in enumerate(inputs)], axis=1)


def _check_samples(study: Study, doc: dict) -> None:
    """Every sample's value in its key's range, and every sample's config valid (cross-key
    rules, step counts): refused before anything runs."""
    for j, inp in enumerate(study.inputs):
        section, name = inp.key.rsplit(".", 1)
        field = SCHEMA[section][name]
        bad = [v for v in study.values[:, j] if not _within(field, v)]
        if bad:
            raise ConfigError(
                f"study.inputs[{j}]: {inp.key} = {inp.dist}"
                f"({', '.join(f'{p:g}' for p in inp.params)}) draws {bad[0]:g}, outside "
                f"{inp.key}'s allowed range {field.allowed()}: narrow the distribution"
            )
    for i in range(study.n):
        try:
            load_config(doc, study.overrides(i))
        except ConfigError as err:
            raise ConfigError(
                f"study sample {i} ({', '.join(study.overrides(i))}): {err}"
            ) from None
