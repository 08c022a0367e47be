"""Material presets and material files (TOML, units in the key names).

A material file has ``law = "anand" | "j2" | "elastic"``, an optional ``description`` and
a ``[params]`` table whose keys are exactly the fields of that law's parameter dataclass.
The presets are such files shipped inside the package (``jaxform/materials/data``, read
with :mod:`importlib.resources`, so an installed jaxform finds them from any directory).
``load_material(name)`` accepts a preset name or a path to a ``.toml`` file and returns
``(law, params)`` with every parameter validated; every failure is a
:class:`MaterialError`, a :class:`jaxform.errors.ConfigError` naming the config key.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from importlib import resources
from pathlib import Path

import jax.numpy as jnp

from jaxform.errors import ConfigError
from jaxform.materials.anand import Anand, AnandParams
from jaxform.materials.elastic import ElasticParams, Hypoelastic
from jaxform.materials.j2 import J2Params, J2Plasticity

# the package-data folder of the presets (declared in pyproject.toml)
PRESET_PACKAGE, PRESET_FOLDER = "jaxform.materials", "data"

# law name -> (law class, params class, {key: (low, high, low_inclusive)})
_POS = (0.0, math.inf, False)
_NONNEG = (0.0, math.inf, True)
LAWS = {
    "anand": (
        Anand,
        AnandParams,
        {
            "A_1_s": _POS,
            "Q_over_R_K": _NONNEG,
            "temperature_K": _POS,
            "xi": _POS,
            "m": (0.0, 1.0, False),
            "s0_MPa": _POS,
            "h0_MPa": _NONNEG,
            "s_hat_MPa": _POS,
            "n": _NONNEG,
            "a": (1.0, math.inf, True),
            "G_MPa": _POS,
            "K_MPa": _POS,
        },
    ),
    "j2": (
        J2Plasticity,
        J2Params,
        {"G_MPa": _POS, "K_MPa": _POS, "sigma_y0_MPa": _POS, "H_MPa": _NONNEG},
    ),
    "elastic": (Hypoelastic, ElasticParams, {"G_MPa": _POS, "K_MPa": _POS}),
}


class MaterialError(ConfigError):
    """A material preset, file or table is invalid; the message names the key and what is
    allowed (a config error: the command line reports it in one line and exits 2)."""


def _preset_files() -> dict:
    """Preset name -> importlib.resources Traversable of its TOML file."""
    folder = resources.files(PRESET_PACKAGE) / PRESET_FOLDER
    return {p.name[:-5]: p for p in folder.iterdir() if p.name.endswith(".toml")}


def available_presets() -> list[str]:
    """Names of the material presets shipped with jaxform.

    Returns:
        the preset names, sorted (e.g. ``al1100_673K``).
    """
    return sorted(_preset_files())


def _range_text(lo, hi, lo_incl):
    left = "[" if lo_incl else "("
    right = ")"
    return f"{left}{lo:g}, {hi:g}{right}"


def material_from_table(law_name: str, params: dict, where: str = "material.params"):
    """Law and parameters from a law name and a flat dict of parameters, validated.

    Arguments:
        law_name: one of :data:`LAWS` (``anand``, ``j2``, ``elastic``).
        params: parameter name -> number, exactly the fields of the law's parameters.
        where: the name of the parameter table in error messages.

    Returns:
        ``(law, params)``: the law object and its parameter pytree (float leaves).
    """
    if not isinstance(law_name, str) or law_name not in LAWS:
        raise MaterialError(f"law = {law_name!r} (for {where}): must be one of {sorted(LAWS)}")
    law_cls, params_cls, ranges = LAWS[law_name]
    unknown = sorted(set(params) - set(ranges))
    if unknown:
        raise MaterialError(
            f"{where}: unknown key(s) {unknown} for law {law_name!r}; allowed: {sorted(ranges)}"
        )
    missing = sorted(set(ranges) - set(params))
    if missing:
        raise MaterialError(f"{where}: missing key(s) {missing} for law {law_name!r}")
    values = {}
    for key, (lo, hi, lo_incl) in ranges.items():
        v = params[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise MaterialError(
                f"{where}.{key} = {v!r}: must be a number in {_range_text(lo, hi, lo_incl)}"
            )
        v = float(v)
        ok_lo = v >= lo if lo_incl else v > lo
        if not (math.isfinite(v) and ok_lo and v < hi):
            raise MaterialError(
                f"{where}.{key} = {v!r}: must lie in {_range_text(lo, hi, lo_incl)}"
            )
        values[key] = jnp.asarray(v)
    return law_cls(), params_cls(**values)


_FORMAT = (
    f"a material file is TOML with law = one of {sorted(LAWS)}, an optional "
    f"description and a [params] table"
)


def _allowed(names) -> str:
    return f"allowed: a preset name ({', '.join(names)}) or the path of a .toml material file"


def load_material(name_or_path: str | Path, key: str = "material.preset"):
    """Law and parameters of a preset or a material file, validated.

    Arguments:
        name_or_path: a preset name (:func:`available_presets`) or the path of a
            material file (TOML).
        key: the config key or flag that gave ``name_or_path``, named in errors.

    Returns:
        ``(law, params)``: the law object and its parameter pytree.

    Raises:
        MaterialError: unknown preset, missing or unreadable file, not TOML, unknown
            law or a parameter missing, unknown or out of range (one line).
    """
    text = str(name_or_path)
    head = f"{key} = {text!r}"
    presets = _preset_files()
    if text in presets:
        return _from_bytes(presets[text].read_bytes(), head)
    path = Path(text)
    if not (text.endswith(".toml") or "/" in text or path.exists()):
        raise MaterialError(f"{head}: no such preset; {_allowed(sorted(presets))}")
    if not path.is_file():
        what = "is a directory" if path.is_dir() else "no such file"
        raise MaterialError(f"{head}: {what}; {_allowed(sorted(presets))}")
    try:
        data = path.read_bytes()
    except OSError as err:
        raise MaterialError(
            f"{head}: cannot read the file ({err.strerror}); {_allowed(sorted(presets))}"
        ) from err
    return _from_bytes(data, head)


def _from_bytes(data: bytes, head: str):
    """(law, params) from the bytes of a material file; errors start with ``head``."""
    try:
        table = tomllib.loads(data.decode("utf-8"))
    except UnicodeDecodeError as err:
        raise MaterialError(f"{head}: not a text (UTF-8) file; {_FORMAT}") from err
    except tomllib.TOMLDecodeError as err:
        raise MaterialError(f"{head}: invalid TOML ({err}); {_FORMAT}") from err
    unknown = sorted(set(table) - {"law", "description", "params"})
    if unknown:
        raise MaterialError(f"{head}: unknown key(s) {unknown}; allowed: law, description, params")
    law = table.get("law")
    if not isinstance(law, str) or law not in LAWS:
        raise MaterialError(f"{head}: law = {law!r}: must be one of {sorted(LAWS)}")
    params = table.get("params")
    if not isinstance(params, dict):
        raise MaterialError(
            f"{head}: needs a [params] table with the keys of law {law!r}: "
            f"{', '.join(LAWS[law][2])}"
        )
    return material_from_table(law, params, where=f"{head}: params")


def params_as_dict(params) -> dict[str, float]:
    return {f.name: float(getattr(params, f.name)) for f in dataclasses.fields(params)}
