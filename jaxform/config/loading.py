"""Reading a config: a TOML file or a nested dict, ``--set`` overrides, every key checked
against the schema and its default filled in, the cross-key rules
(:mod:`jaxform.config.rules`) run on the typed sections; and writing one back
(:func:`dump_config`), the sections a user wrote (:func:`given_sections`,
:func:`defaulted_sections`) and the key reference (:func:`describe_schema`).  This module
imports no JAX."""

from __future__ import annotations

import copy
import tomllib
from collections.abc import Iterable
from os import PathLike
from pathlib import Path
from typing import Any

import tomli_w

from jaxform.config.die_sections import FRICTION_DIES, INHERITED
from jaxform.config.document import SCHEMA, WORKPIECES, Config, applies, typed, workpiece_section
from jaxform.config.rules import check_document
from jaxform.config.schema import check_value
from jaxform.config.workpiece_sections import TRIGGERS
from jaxform.errors import ConfigError
from jaxform.material_files import load_thermal_properties


def parse_override(text: str) -> tuple[str, str, Any]:
    """Split ``section.key=value``; the value is a TOML value, else a bare string."""
    if "=" not in text:
        raise ConfigError(f"malformed override {text!r}: expected section.key=value")
    dotted, raw = (s.strip() for s in text.split("=", 1))
    section, dot, key = dotted.rpartition(".")  # die.friction.m: section die.friction
    if not dot or not section or not key or "." in key:
        raise ConfigError(
            f"malformed override {text!r}: the key must be section.key, "
            f"sections: {', '.join(SCHEMA)}"
        )
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw
    return section, key, value


# keys that may be left out even though they have no default (the rules check them)
_CONDITIONAL = {
    ("die", "speed_mm_s"),
    ("die", "reduction"),
    ("material", "density_kg_m3"),
    ("material", "specific_heat_J_kgK"),
    ("material", "conductivity_W_mK"),
}


def load_config(path_or_dict: str | PathLike | dict, overrides: Iterable[str] = ()) -> dict:
    """Read a TOML scene (path) or nested dict, apply overrides and validate.

    Arguments:
        path_or_dict: the path of a TOML scene, or the same as a nested dict.
        overrides: ``section.key=value`` strings (the value a TOML value, else a string).

    Returns:
        a new nested dict with every schema key (defaults filled in).

    Raises:
        ConfigError: one line naming the dotted key and what is allowed.
    """
    raw = copy.deepcopy(path_or_dict) if isinstance(path_or_dict, dict) else read_toml(path_or_dict)
    # a multi-stage process is read by jaxform.process_config.load_document; here its
    # base sections are checked first, then it is refused (a command of one scene)
    process = raw.pop("process", None)
    _lift_friction_tables(raw)
    apply_overrides(raw, overrides)
    kind = _check_names(raw)
    out = _filled(raw, kind)
    _closed_die_remeshing(raw, out)
    _thermal_properties(out)
    check_document(typed(out), raw)
    if process is not None:
        raise ConfigError(
            "[[process.operation]]: a multi-stage process runs with `jaxform run` only "
            "(design and taylor-test take a config of one forming operation)"
        )
    return out


def apply_overrides(raw: dict, overrides: Iterable[str]) -> None:
    """Write ``section.key=value`` overrides into a raw document (in place)."""
    for text in overrides:
        section, key, value = parse_override(text)
        sec = raw.setdefault(section, {})
        if not isinstance(sec, dict):
            raise ConfigError(f"{section}: must be a table of keys, not {sec!r}")
        sec[key] = value


def _check_names(raw: dict) -> str:
    """The workpiece of a raw document whose sections and keys are all in the schema and
    apply to that workpiece."""
    for section, table in raw.items():
        if section not in SCHEMA:
            raise ConfigError(f"unknown section {section!r}; allowed sections: {', '.join(SCHEMA)}")
        if not isinstance(table, dict):
            raise ConfigError(
                f"{section}: must be a table of keys ({', '.join(SCHEMA[section])}), not {table!r}"
            )
        for key in table:
            if key not in SCHEMA[section]:
                raise ConfigError(
                    f"unknown key {section}.{key}; allowed keys of [{section}]: "
                    f"{', '.join(SCHEMA[section])}"
                )
    kind = workpiece_section(raw)
    for section in raw:
        if not applies(section, kind):
            raise ConfigError(
                f"[{section}] does not apply to a [{kind}] scene; allowed sections: "
                f"{', '.join(s for s in SCHEMA if applies(s, kind))}"
            )
    return kind


def _filled(raw: dict, kind: str) -> dict[str, dict[str, Any]]:
    """Every section of a ``kind`` scene with every key: the given value checked against
    its field, else the default (a required key left out: ConfigError)."""
    out: dict[str, dict[str, Any]] = {}
    for section, fields in SCHEMA.items():
        if not applies(section, kind):
            continue
        given = raw.get(section, {})
        out[section] = {}
        for key, f in fields.items():
            name = f"{section}.{key}"
            optional = (section, key) in _CONDITIONAL | INHERITED
            if key in given and not (given[key] is None and optional):
                out[section][key] = check_value(name, f, given[key])
            elif f.default is None and not optional:
                raise ConfigError(
                    f"missing required key {name} ({f.kind} in {f.allowed()}): {f.doc}"
                )
            else:
                out[section][key] = copy.deepcopy(f.default)
    return out


def _lift_friction_tables(raw: dict) -> None:
    """Move each TOML sub-table [die.friction] (raw["die"]["friction"]) to the section
    "die.friction" of the document (as [bottom_die.friction], [side_die.friction])."""
    for die in FRICTION_DIES:
        table = raw.get(die)
        if isinstance(table, dict) and "friction" in table:
            sub = table.pop("friction")
            if not isinstance(sub, dict):
                raise ConfigError(
                    f"{die}.friction: must be a table of keys (model, mu, m), not {sub!r}"
                )
            raw.setdefault(f"{die}.friction", {}).update(sub)


def _thermal_properties(out: dict) -> None:
    """Fill material.density_kg_m3, specific_heat_J_kgK and conductivity_W_mK from the
    preset's [thermal] table where not given (a coupled run needs all three: the rules
    check that)."""
    mat = out["material"]
    keys = ("density_kg_m3", "specific_heat_J_kgK", "conductivity_W_mK")
    if any(mat[k] is None for k in keys):
        preset = load_thermal_properties(mat["preset"])
        for k in keys:
            if mat[k] is None:
                mat[k] = preset.get(k)


# the quality trigger a closed die remeshes on when its config sets no trigger of its own
CLOSED_DIE_QUALITY = 0.3


def _closed_die_remeshing(raw: dict, out: dict) -> None:
    """A closed die (die.closed = true) whose config sets no remesh trigger and no
    rezoning remeshes when an element's corner quality falls below CLOSED_DIE_QUALITY:
    material wraps the die's corners there, which no fixed mesh follows.  The trigger
    costs a pause only where it fires; the resolved config (config.toml) shows it."""
    die = out.get("die")
    if die is None or not die["closed"] or "remesh" not in out:
        return
    given = raw.get("remesh", {})
    if any(k in given for k in TRIGGERS) or out["mesh"].get("rezone_quality", 0.0) > 0.0:
        return
    out["remesh"]["quality_below"] = CLOSED_DIE_QUALITY


def given_sections(path_or_dict: str | PathLike | dict, overrides: Iterable[str] = ()) -> set:
    """The sections a config document (and its ``--set`` overrides) writes itself; every
    other section of the scene takes its defaults.  The document must have loaded
    (:func:`load_config`)."""
    raw = path_or_dict if isinstance(path_or_dict, dict) else read_toml(path_or_dict)
    return set(raw) | {parse_override(text)[0] for text in overrides}


def defaulted_sections(cfg: Config, given: set, command: str) -> list[str]:
    """One line for each section that a user would expect to write but that the
    validated config ``cfg`` took from the defaults (``given``: :func:`given_sections`):
    [material] always, [design] for ``jaxform design``."""
    lines = []
    if "material" not in given:
        lines.append(
            f"material: {cfg.material.preset} (default: the config has no [material] section)"
        )
    if command == "design" and "design" not in given:
        d = cfg.design
        lines.append(
            f"design: the config has no [design] section: the defaults, variables "
            f"{', '.join(d.variables)}, objective {d.objective}, {d.iterations} "
            f"iterations of {d.optimizer}"
        )
    return lines


def read_toml(path: str | PathLike) -> dict:
    """The TOML document at ``path`` (UTF-8, a byte-order mark allowed), or ConfigError
    naming the file and what is wrong with it."""
    p = Path(path)
    if p.is_dir():
        raise ConfigError(f"{path}: is a folder, not a TOML config file")
    try:
        text = p.read_bytes().decode("utf-8-sig")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the config: {exc.strerror or exc}") from exc
    except UnicodeDecodeError as exc:
        raise ConfigError(
            f"{path}: not a UTF-8 text file (byte {exc.start}): a config is TOML text"
        ) from exc
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: invalid TOML: {exc}") from exc
    if not raw:
        raise ConfigError(
            f"{path}: empty config: give a workpiece section "
            f"({', '.join(f'[{w}]' for w in WORKPIECES)}) and its keys"
        )
    return raw


def read_document(path: str | PathLike) -> dict:
    """The raw TOML document of a scene file (not validated: :func:`load_config` takes it
    as it takes the path), for callers that send a scene to another machine (jaxform
    study's workers need not see the file).  ConfigError as for the path."""
    return read_toml(path)


def toml_form(cfg: dict) -> dict:
    """A (resolved) config as its TOML file holds it: keys whose value is unset left out,
    a die's friction table as its sub-table [die.friction] where it sets a key."""
    clean = {s: {k: v for k, v in t.items() if v is not None} for s, t in cfg.items()}
    for name in [s for s in clean if "." in s]:
        table = clean.pop(name)
        if table:
            die = name.split(".")[0]
            clean[die] = {**clean.get(die, {}), "friction": table}
    return clean


def dump_config(cfg: dict, path: str | PathLike) -> None:
    """Write a (resolved) config as TOML (:func:`toml_form`)."""
    Path(path).write_bytes(tomli_w.dumps(toml_form(cfg)).encode())


def describe_schema() -> str:
    """A Markdown table (key | type | default | allowed | meaning) of every key."""
    rows = ["| key | type | default | allowed | meaning |", "|---|---|---|---|---|"]
    for section, fields in SCHEMA.items():
        for key, f in fields.items():
            if (section, key) in INHERITED:
                default = "[friction]'s"
            elif f.default is None:
                default = "required"
            elif f.kind == "bool":
                default = str(f.default).lower()
            elif f.kind == "str":
                default = f'"{f.default}"'
            elif f.kind in ("floats", "strs", "points"):
                default = (
                    "["
                    + ", ".join(f'"{v}"' if isinstance(v, str) else f"{v:g}" for v in f.default)
                    + "]"
                )
            else:
                default = f"{f.default:g}" if f.kind == "float" else str(f.default)
            cells = [f"`{section}.{key}`", f.kind, default, f.allowed(), f.doc]
            rows.append("| " + " | ".join(c.replace("|", r"\|") for c in cells) + " |")
    return "\n".join(rows) + "\n"
