"""Material presets: TOML files under ``configs/materials/`` (units in the key names).

A preset file has ``law = "anand" | "j2" | "elastic"`` and a ``[params]`` table whose
keys are exactly the fields of that law's parameter dataclass.  ``load_material(name)``
accepts a preset name (file stem in configs/materials) or a path to a TOML file and
returns ``(law, params)`` with every parameter validated.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from pathlib import Path

import jax.numpy as jnp

from jaxform.materials.anand import Anand, AnandParams
from jaxform.materials.elastic import ElasticParams, Hypoelastic
from jaxform.materials.j2 import J2Params, J2Plasticity

PRESET_DIR = Path(__file__).resolve().parents[2] / "configs" / "materials"

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


class MaterialError(ValueError):
    """A material table is invalid; the message names the key and the allowed range."""


def available_presets() -> list[str]:
    return sorted(p.stem for p in PRESET_DIR.glob("*.toml"))


def _range_text(lo, hi, lo_incl):
    left = "[" if lo_incl else "("
    right = ")"
    return f"{left}{lo:g}, {hi:g}{right}"


def material_from_table(law_name: str, params: dict, where: str = "material"):
    """Build (law, params) from a law name and a flat dict of parameters, validated."""
    if law_name not in LAWS:
        raise MaterialError(f"{where}.law = {law_name!r}: must be one of {sorted(LAWS)}")
    law_cls, params_cls, ranges = LAWS[law_name]
    unknown = sorted(set(params) - set(ranges))
    if unknown:
        raise MaterialError(
            f"{where}.params: unknown key(s) {unknown} for law {law_name!r}; "
            f"allowed: {sorted(ranges)}"
        )
    missing = sorted(set(ranges) - set(params))
    if missing:
        raise MaterialError(f"{where}.params: missing key(s) {missing} for law {law_name!r}")
    values = {}
    for key, (lo, hi, lo_incl) in ranges.items():
        v = params[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise MaterialError(f"{where}.params.{key} = {v!r}: must be a number")
        v = float(v)
        ok_lo = v >= lo if lo_incl else v > lo
        if not (math.isfinite(v) and ok_lo and v < hi):
            raise MaterialError(
                f"{where}.params.{key} = {v!r}: must lie in {_range_text(lo, hi, lo_incl)}"
            )
        values[key] = jnp.asarray(v)
    return law_cls(), params_cls(**values)


def load_material(name_or_path: str | Path):
    """(law, params) from a preset name in configs/materials or a TOML file path."""
    path = Path(name_or_path)
    if path.suffix != ".toml":
        path = PRESET_DIR / f"{name_or_path}.toml"
    if not path.is_file():
        raise MaterialError(
            f"material.preset = {str(name_or_path)!r}: no such preset; "
            f"available: {available_presets()} (or give a path to a .toml file)"
        )
    with open(path, "rb") as fh:
        table = tomllib.load(fh)
    return material_from_table(table.get("law", ""), table.get("params", {}), where=path.stem)


def params_as_dict(params) -> dict[str, float]:
    return {f.name: float(getattr(params, f.name)) for f in dataclasses.fields(params)}
