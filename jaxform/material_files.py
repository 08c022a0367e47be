"""Reading material files and presets (TOML), without JAX: the config reads the
thermal table of a preset through here.

A preset is a material file shipped inside the package (``jaxform/materials/data``, read
with :mod:`importlib.resources` from the ``jaxform`` package, so neither JAX nor the laws
are imported).  :mod:`jaxform.materials.presets` turns a file's ``[params]`` into a law and
its parameters; this module reads the file and its optional ``[thermal]`` table.
"""

from __future__ import annotations

import math
import tomllib
from importlib import resources
from pathlib import Path

from jaxform.errors import ConfigError

LAW_NAMES = ("anand", "elastic", "j2")
_POS = (0.0, math.inf, False)
# a material file's optional [thermal] table: key -> allowed range (units in the names)
THERMAL_KEYS = {
    "density_kg_m3": _POS,
    "specific_heat_J_kgK": _POS,
    "conductivity_W_mK": _POS,
}


class MaterialError(ConfigError):
    """A material preset, file or table is invalid; the message names the key and what is
    allowed (a config error: the command line reports it in one line and exits 2)."""


def _preset_files() -> dict:
    """Preset name -> importlib.resources Traversable of its TOML file."""
    folder = resources.files("jaxform") / "materials" / "data"
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


def checked_number(v, name: str, lo: float, hi: float, lo_incl: bool) -> float:
    """v as a float, or MaterialError naming ``name`` and the allowed range."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise MaterialError(f"{name} = {v!r}: must be a number in {_range_text(lo, hi, lo_incl)}")
    v = float(v)
    ok_lo = v >= lo if lo_incl else v > lo
    if not (math.isfinite(v) and ok_lo and v < hi):
        raise MaterialError(f"{name} = {v!r}: must lie in {_range_text(lo, hi, lo_incl)}")
    return v


_FORMAT = (
    f"a material file is TOML with law = one of {list(LAW_NAMES)}, an optional "
    f"description, a [params] table and an optional [thermal] table"
)


def _allowed(names) -> str:
    return f"allowed: a preset name ({', '.join(names)}) or the path of a .toml material file"


def load_thermal_properties(name_or_path: str | Path, key: str = "material.preset") -> dict:
    """The [thermal] table of a preset or material file, validated: density_kg_m3,
    specific_heat_J_kgK, conductivity_W_mK (floats); {} if the file has none."""
    table, head = read_material_file(name_or_path, key)
    return thermal_table(table, head)


def thermal_table(table: dict, head: str) -> dict:
    """The validated [thermal] table of a material file's ``table`` ({} if none); errors
    start with ``head``."""
    th = table.get("thermal", {})
    if not isinstance(th, dict):
        raise MaterialError(f"{head}: thermal must be a table of {', '.join(THERMAL_KEYS)}")
    unknown = sorted(set(th) - set(THERMAL_KEYS))
    if unknown:
        raise MaterialError(
            f"{head}: unknown key(s) {unknown} in [thermal]; allowed: {', '.join(THERMAL_KEYS)}"
        )
    if th and set(th) != set(THERMAL_KEYS):
        raise MaterialError(
            f"{head}: [thermal] needs all of {', '.join(THERMAL_KEYS)} "
            f"(missing {sorted(set(THERMAL_KEYS) - set(th))})"
        )
    return {k: checked_number(th[k], f"{head}: thermal.{k}", *r) for k, r in THERMAL_KEYS.items()
            if k in th}  # fmt: skip


def read_material_file(name_or_path: str | Path, key: str) -> tuple[dict, str]:
    """(the TOML table of a preset or material file, the head of its error messages)."""
    text = str(name_or_path)
    head = f"{key} = {text!r}"
    presets = _preset_files()
    if text in presets:
        return _from_bytes(presets[text].read_bytes(), head), head
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
    return _from_bytes(data, head), head


def _from_bytes(data: bytes, head: str) -> dict:
    """The table of a material file's bytes; errors start with ``head``."""
    try:
        table = tomllib.loads(data.decode("utf-8"))
    except UnicodeDecodeError as err:
        raise MaterialError(f"{head}: not a text (UTF-8) file; {_FORMAT}") from err
    except tomllib.TOMLDecodeError as err:
        raise MaterialError(f"{head}: invalid TOML ({err}); {_FORMAT}") from err
    unknown = sorted(set(table) - {"law", "description", "params", "thermal"})
    if unknown:
        raise MaterialError(
            f"{head}: unknown key(s) {unknown}; allowed: law, description, params, thermal"
        )
    return table
