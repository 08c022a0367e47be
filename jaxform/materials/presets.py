"""Material presets and material files (TOML, units in the key names).

A material file has ``law = "anand" | "j2" | "elastic"``, an optional ``description``, a
``[params]`` table whose keys are the fields of that law's parameter dataclass (those in
:data:`OPTIONAL` may be left out) and an optional ``[thermal]`` table (density_kg_m3,
specific_heat_J_kgK, conductivity_W_mK) that coupled thermal runs need.
The presets are such files shipped inside the package (``jaxform/materials/data``, read
with :mod:`importlib.resources`, so an installed jaxform finds them from any directory).
``load_material(name)`` accepts a preset name or a path to a ``.toml`` file and returns
``(law, params)`` with every parameter validated; every failure is a
:class:`MaterialError`, a :class:`jaxform.errors.ConfigError` naming the config key.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import jax.numpy as jnp

from jaxform.material_files import (
    MaterialError,
    available_presets,
    checked_number,
    load_thermal_properties,
    read_material_file,
    thermal_table,
)
from jaxform.materials.anand import Anand, AnandParams
from jaxform.materials.elastic import ElasticParams, Hypoelastic
from jaxform.materials.j2 import J2Params, J2Plasticity

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
        {
            "G_MPa": _POS,
            "K_MPa": _POS,
            "sigma_y0_MPa": _POS,
            "H_MPa": _NONNEG,
            "yield_slope_MPa_K": (-math.inf, math.inf, False),
            "reference_temperature_K": _POS,
        },
    ),
    "elastic": (Hypoelastic, ElasticParams, {"G_MPa": _POS, "K_MPa": _POS}),
}


# parameters a material file may leave out (law -> {key: default})
OPTIONAL = {"j2": {"yield_slope_MPa_K": 0.0, "reference_temperature_K": 293.15}}


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
    params = {**OPTIONAL.get(law_name, {}), **params}
    missing = sorted(set(ranges) - set(params))
    if missing:
        raise MaterialError(f"{where}: missing key(s) {missing} for law {law_name!r}")
    values = {key: jnp.asarray(checked_number(params[key], f"{where}.{key}", *r))
              for key, r in ranges.items()}  # fmt: skip
    return law_cls(), params_cls(**values)


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
    table, head = read_material_file(name_or_path, key)
    law = table.get("law")
    if not isinstance(law, str) or law not in LAWS:
        raise MaterialError(f"{head}: law = {law!r}: must be one of {sorted(LAWS)}")
    params = table.get("params")
    if not isinstance(params, dict):
        raise MaterialError(
            f"{head}: needs a [params] table with the keys of law {law!r}: "
            f"{', '.join(LAWS[law][2])}"
        )
    thermal_table(table, head)  # a bad [thermal] table is an error even for isothermal runs
    return material_from_table(law, params, where=f"{head}: params")


def params_as_dict(params) -> dict[str, float]:
    return {f.name: float(getattr(params, f.name)) for f in dataclasses.fields(params)}


__all__ = [
    "LAWS",
    "MaterialError",
    "available_presets",
    "load_material",
    "load_thermal_properties",
    "material_from_table",
    "params_as_dict",
]
