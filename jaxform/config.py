"""TOML scene configs: load, override, validate and resolve defaults.

A scene is a two-level TOML document ``[section] key = value``. :data:`SCHEMA`
lists every allowed key with its type, default (``None`` = required), allowed
range or choices and a one-line description; keys carry their unit in the name.
:func:`load_config` returns a new nested dict with every key present, or raises
:class:`ConfigError` naming the full dotted key before anything else happens.
This module does not import JAX.
"""

from __future__ import annotations

import copy
import math
import tomllib
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any, Iterable

import tomli_w

__all__ = ["ConfigError", "Field", "SCHEMA", "load_config", "dump_config", "describe_schema"]


class ConfigError(ValueError):
    """An invalid scene config; the message names the dotted key and what is allowed."""


@dataclass(frozen=True)
class Field:
    """One config key: kind, default (None = required), allowed range or choices, doc."""

    kind: str  # "float" | "int" | "str" | "bool" | "floats" | "strs" (lists) | "points" (list of [a, b])
    default: Any = None
    low: float | None = None
    high: float | None = None
    low_inclusive: bool = True
    high_inclusive: bool = True
    choices: tuple[str, ...] | None = None
    doc: str = ""

    def allowed(self) -> str:
        """Human-readable allowed values: an interval, a choice list or the kind."""
        if self.choices is not None:
            return "one of " + ", ".join(repr(c) for c in self.choices)
        if self.kind in ("float", "int") and (self.low is not None or self.high is not None):
            lo = "-inf" if self.low is None else _num(self.low)
            hi = "inf" if self.high is None else _num(self.high)
            left = "[" if self.low is not None and self.low_inclusive else "("
            right = "]" if self.high is not None and self.high_inclusive else ")"
            return f"{left}{lo}, {hi}{right}"
        return f"any {self.kind}"


def _num(x: float) -> str:
    """Format a bound compactly (``0``, ``1``, ``2000``, ``0.5``)."""
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e15 else repr(float(x))


SCHEMA: dict[str, dict[str, Field]] = {
    "billet": {
        "diameter_mm": Field("float", None, 0.0, None, False, False, doc="billet diameter (mm)"),
        "height_mm": Field("float", None, 0.0, None, False, False, doc="billet height (mm)"),
    },
    "ring": {
        "outer_diameter_mm": Field("float", None, 0.0, None, False, False,
                                   doc="ring outer diameter (mm)"),
        "inner_diameter_mm": Field("float", None, 0.0, None, False, False,
                                   doc="ring inner diameter (mm), < outer"),
        "height_mm": Field("float", None, 0.0, None, False, False, doc="ring height (mm)"),
    },
    "block": {
        "width_mm": Field("float", None, 0.0, None, False, False,
                          doc="plane-strain block for indentation: modelled half-width from the "
                              "symmetry line x = 0 (mm)"),
        "depth_mm": Field("float", None, 0.0, None, False, False,
                          doc="block depth (mm): frictionless support at y = 0, indented face at "
                              "y = depth"),
        "fine_width_mm": Field("float", None, 0.0, None, False, False,
                               doc="width of the zone of equal elements at the indented face "
                                   "(mm), <= block.width_mm"),
        "fine_depth_mm": Field("float", None, 0.0, None, False, False,
                               doc="depth of the zone of equal elements below the indented face "
                                   "(mm), <= block.depth_mm"),
        "growth": Field("float", 1.2, 1.0, 3.0, False, True,
                        doc="size ratio of neighbouring elements outside the fine zone"),
    },
    "membrane": {
        "corners_mm": Field("points", None,
                            doc="the 4 corners [x_mm, y_mm] of a convex plane-strain panel, "
                                "counter-clockwise; edges: bottom 1-2, right 2-3, top 3-4, left 4-1"),
        "clamped_edge": Field("str", "left", choices=("bottom", "right", "top", "left"),
                              doc="edge with u = 0"),
        "tip_mm": Field("floats", [], doc="[x_mm, y_mm] of the point whose displacement the "
                        "history records as tip_ux_mm, tip_uy_mm (nearest node; [] = corner 3)"),
    },
    "load": {
        "edge": Field("str", "right", choices=("bottom", "right", "top", "left"),
                      doc="membrane edge carrying a uniform dead traction"),
        "force_x_N": Field("float", 0.0, doc="x-resultant of the traction (N per mm of depth), "
                           "spread uniformly over the edge's initial length"),
        "force_y_N": Field("float", 0.0, doc="y-resultant of the traction (N per mm of depth), "
                           "spread uniformly over the edge's initial length"),
        "ramp_time_s": Field("float", 1.0, 0.0, None, False, False,
                             doc="the load grows linearly from 0 to full over this time (s); "
                                 "the run ends there"),
    },
    "mesh": {
        "nr": Field("int", 10, 1, 2000, doc="elements across the radius of the quarter section "
                    "(block: across the fine zone; membrane: along edges bottom and top)"),
        "nz": Field("int", 10, 1, 2000, doc="elements along the half height of the quarter section "
                    "(block: down the fine zone; membrane: along edges left and right)"),
        "element": Field("str", "q1q1", choices=("q1q1", "q1p0", "q4"),
                         doc="element formulation: stabilized mixed u-p (seed), "
                             "mean-dilatation F-bar, plain displacement"),
        "geometry": Field("str", "axisymmetric", choices=("axisymmetric", "plane_strain"),
                          doc="2-D idealization (plane strain: forces per mm of depth)"),
        "stabilization": Field("float", 0.1, 0.0, None, True, False,
                               doc="q1q1 pressure stabilization theta in tau = theta h^2/(2G) "
                                   "(the thesis used 1e-4)"),
        "file": Field("str", "", doc="optional gmsh/meshio quadrilateral mesh file replacing "
                                     "the structured mesh ('' = structured); line groups name the "
                                     "boundary sets (symmetry, top required; axis, side, inner, "
                                     "outer), point groups node sets (e.g. one axis node)"),
        "rezone_quality": Field("float", 0.0, 0.0, 1.0, True, False,
                                doc="rezone (relocate the nodes, carry the state over) after a "
                                    "step whose worst element corner quality (jaxform.rezone: "
                                    "1 for squares) falls below this (0 = never; structured "
                                    "meshes only)"),
    },
    "material": {
        "preset": Field("str", "al1100_673K",
                        doc="material preset name in configs/materials or a .toml path"),
    },
    "die": {
        "speed_mm_s": Field("float", None, 0.0, None, False, False,
                            doc="ram speed (mm/s): the dies close at this speed (each moves at "
                                "half of it towards the mid-plane; a block's die at all of it); "
                                "required unless a path table is given"),
        "reduction": Field("float", None, 0.0, 1.0, False, False,
                           doc="final height reduction (fraction of the initial height; block: "
                               "of its depth); the run ends when the ram stroke reaches it"),
        "profile_mm": Field("points", [], doc="top-die profile as [r_mm, z_mm] points at t = 0, "
                            "walked with the workpiece on the right (from the axis outward for "
                            "a top die); [] = flat die on the billet's top face"),
        "profile_kind": Field("str", "polyline", choices=("polyline", "spline"),
                              doc="straight segments between the points, or the Catmull-Rom "
                                  "spline through them"),
        "path_time_s": Field("floats", [], doc="die path table: times (s), starting at 0 "
                             "([] = constant speed)"),
        "path_travel_mm": Field("floats", [], doc="die path table: downward travel of the top "
                                "die relative to the mid-plane at those times (mm), starting "
                                "at 0 (the ram stroke is twice it)"),
        "corner_radius_mm": Field("float", 0.5, 0.0, None, False, False,
                                  doc="radius of the arcs that round the profile's vertices "
                                      "(mm): the die surface is C1; where two segments are "
                                      "too short for it, the arc runs between their midpoints "
                                      "(so sampled fillets and splines keep their shape)"),
        "closed": Field("bool", False, doc="the profile closes a cavity with the mid-plane: "
                        "report die_fill (cavity volume filled with material / cavity volume) in the "
                        "history"),
    },
    "friction": {
        "model": Field("str", "none", choices=("none", "coulomb", "shear", "sticking"),
                       doc="die-workpiece friction law"),
        "mu": Field("float", 0.0, 0.0, 10.0, doc="Coulomb coefficient (friction.model = coulomb)"),
        "m": Field("float", 0.0, 0.0, 1.0, doc="shear friction factor, tau = m sigma_eq/sqrt(3) "
                   "(friction.model = shear)"),
    },
    "time": {
        "dt_s": Field("float", None, 0.0, None, False, False, doc="time step (s)"),
        "alpha": Field("float", 0.5, 0.0, 1.0,
                       doc="generalized mid-point parameter of the strain increment"),
    },
    "solver": {
        "max_newton_iterations": Field("int", 25, 1, 1000,
                                       doc="Newton iterations per step before a cutback (modified "
                                           "Newton: those with a new Jacobian; up to 3x as "
                                           "many more with a kept factorization)"),
        "rtol": Field("float", 1e-10, 0.0, 1.0, False, False,
                      doc="relative residual tolerance of Newton"),
        "max_cutbacks": Field("int", 6, 0, 30, doc="times a failed step may be halved"),
        "line_search": Field("bool", True, doc="backtracking line search in Newton"),
        "linear": Field("str", "auto", choices=("auto", "dense", "sparse", "jax-sparse"),
                        doc="linear solver backend (auto: on CPU dense LU below 100 unknowns, "
                            "klujax sparse LU above; on a GPU dense LU below 20 000, "
                            "jax-sparse (cuSolver) above; see jaxform/linear.py)"),
        "newton": Field("str", "auto", choices=("auto", "newton", "modified"),
                        doc="newton: a new Jacobian and factorization every iteration; "
                            "modified: one factorization kept across iterations and steps, "
                            "refreshed when a step contracts the residual by less than "
                            "2x (needs linear = dense or sparse); auto: modified on the "
                            "sparse backend from MODIFIED_MIN_UNKNOWNS unknowns, newton "
                            "below (see jaxform/solver.py)"),
        "adjoint_memory_mb": Field("float", 4096.0, 0.0, None,
                                   doc="memory (MB) a gradient run may hold in forward "
                                       "factorizations kept for its reverse pass, which then "
                                       "refines each step's adjoint solve with the kept "
                                       "factors instead of factoring again; the last steps "
                                       "that fit are kept, the others factor in the reverse "
                                       "pass (0: none kept; ~69 MB a step at 100 x 100 with "
                                       "klujax; see jaxform/gradients.py)"),
        "chunk_steps": Field("int", 8, 1, 10000,
                             doc="load steps per compiled chunk (progress is reported between chunks)"),
        "compilation_cache_dir": Field("str", "auto",
                                       doc="where compiled programs are kept for the next run: "
                                           "a directory, 'off', or 'auto' (the environment "
                                           "variable JAXFORM_CACHE_DIR, else "
                                           "~/.cache/jaxform; see jaxform/cache.py)"),
    },
    "output": {
        "fields": Field("bool", True, doc="write ParaView fields (VTU series)"),
        "plots": Field("bool", True, doc="write PNG plots"),
        "profile_strokes_mm": Field("floats", [], doc="ram strokes (mm) at which the contact "
                                    "pressure/slip profile is plotted ([] = 25/50/75/100 %)"),
    },
    "design": {
        "objective": Field("str", "forging_work", choices=(
            "forging_work", "peak_force", "side_straightness", "shape_target", "force_misfit",
            "eqps_spread", "die_fill"),
            doc="design objective (jaxform design / taylor-test), a function of the run: "
                "force integral over stroke (N mm), peak ram force (N), mean squared "
                "deviation of the final side from straight (mm^2), of chosen nodes from "
                "target positions (mm^2), force-stroke misfit against a target curve, "
                "variance of eqps, 1 - die fill"),
        "variables": Field("strs", ["material"], choices=(
            "material", "friction", "speed", "preform", "nodes", "die"),
            doc="design variable groups jaxform design optimizes"),
        "material_params": Field("strs", ["s0_MPa", "h0_MPa", "s_hat_MPa"],
                                 doc="material parameters of the 'material' group (names "
                                     "of the law's parameters)"),
        "material_start_factor": Field("float", 1.0, 0.0, None, False, True,
                                       doc="the design starts from the material parameters "
                                           "times this (e.g. 0.7 to identify from 30 % off)"),
        "preform_modes": Field("int", 3, 1, 20, doc="cosine modes of the preform profile"),
        "preform_amplitude_max": Field("float", 0.2, 0.0, 0.9, False, True,
                                       doc="bound on each preform mode amplitude (fraction "
                                           "of the radius)"),
        "node_offset_max_mm": Field("float", 0.1, 0.0, None, False, True,
                                    doc="bound on each initial node coordinate's offset of "
                                        "the 'nodes' group (mm)"),
        "die_points": Field("floats", [], doc="indices of die.profile_mm points whose z is "
                            "a design variable ([] = all)"),
        "die_offset_max_mm": Field("float", 1.0, 0.0, None, False, True,
                                   doc="bound on each die point's vertical offset (mm)"),
        "bound_factor": Field("float", 2.0, 1.0, None, False, True,
                              doc="material parameters and ram speed stay within "
                                  "[p0 / factor, p0 * factor]"),
        "target_csv": Field("str", "", doc="target for force_misfit (CSV with stroke_mm, "
                            "force_N) or shape_target (CSV with node, r_mm, z_mm)"),
        "optimizer": Field("str", "lbfgs", choices=("lbfgs", "adam"),
                           doc="optax optimizer (L-BFGS with zoom line search, or Adam)"),
        "iterations": Field("int", 20, 1, 10000, doc="optimizer iterations"),
        "learning_rate": Field("float", 0.05, 0.0, None, False, False,
                               doc="Adam step size in the scaled design variables"),
    },
}

# Exactly one workpiece section: a solid billet, a ring, an indented block (all pressed by
# a die) or a membrane (clamped, loaded by a traction; no die).
WORKPIECES = ("billet", "ring", "block", "membrane")
# sections that only some workpieces use
_DIE_SECTIONS = ("die", "friction")
_LOAD_SECTIONS = ("load",)


def _workpiece(raw: dict) -> str:
    given = [w for w in WORKPIECES if w in raw]
    if len(given) != 1:
        raise ConfigError(f"give exactly one workpiece section, "
                          f"{', '.join(f'[{w}]' for w in WORKPIECES)} "
                          f"(found {', '.join(given) or 'none'})")
    return given[0]


def _applies(section: str, kind: str) -> bool:
    """Whether a section belongs in a scene with workpiece ``kind``."""
    if section in WORKPIECES:
        return section == kind
    if section in _DIE_SECTIONS:
        return kind != "membrane"
    if section in _LOAD_SECTIONS:
        return kind == "membrane"
    return True


def _parse_override(text: str) -> tuple[str, str, Any]:
    """Split ``section.key=value``; the value is a TOML value, else a bare string."""
    if "=" not in text:
        raise ConfigError(f"malformed override {text!r}: expected section.key=value")
    dotted, raw = (s.strip() for s in text.split("=", 1))
    section, dot, key = dotted.partition(".")
    if not dot or not section or not key or "." in key:
        raise ConfigError(f"malformed override {text!r}: the key must be section.key, "
                          f"sections: {', '.join(SCHEMA)}")
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw
    return section, key, value


def _check(name: str, f: Field, value: Any) -> Any:
    """Return ``value`` converted to the field's kind, or raise ConfigError."""
    if f.kind in ("floats", "strs", "points"):
        return _check_list(name, f, value)
    if f.kind == "bool":
        if not isinstance(value, bool):
            raise ConfigError(f"{name} = {value!r}: must be a bool (true or false)")
        return value
    if f.kind == "str":
        if not isinstance(value, str):
            raise ConfigError(f"{name} = {value!r}: must be a string, {f.allowed()}")
        if f.choices is not None and value not in f.choices:
            raise ConfigError(f"{name} = {value!r}: must be {f.allowed()}")
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{name} = {value!r}: must be a{'n' if f.kind == 'int' else ''} "
                          f"{f.kind} in {f.allowed()}")
    if f.kind == "int" and not isinstance(value, int):
        raise ConfigError(f"{name} = {value!r}: must be an int in {f.allowed()}")
    value = int(value) if f.kind == "int" else float(value)
    ok = not (isinstance(value, float) and math.isnan(value))
    if f.low is not None:
        ok = ok and (value >= f.low if f.low_inclusive else value > f.low)
    if f.high is not None:
        ok = ok and (value <= f.high if f.high_inclusive else value < f.high)
    if not ok:
        raise ConfigError(f"{name} = {value!r}: must lie in {f.allowed()}")
    return value


def _is_num(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _check_list(name: str, f: Field, value: Any) -> list:
    if not isinstance(value, list):
        raise ConfigError(f"{name} = {value!r}: must be a list ({f.doc})")
    if f.kind == "floats":
        if not all(_is_num(v) for v in value):
            raise ConfigError(f"{name} = {value!r}: must be a list of finite numbers")
        return [float(v) for v in value]
    if f.kind == "strs":
        if not all(isinstance(v, str) for v in value):
            raise ConfigError(f"{name} = {value!r}: must be a list of strings")
        bad = [v for v in value if f.choices is not None and v not in f.choices]
        if bad:
            raise ConfigError(f"{name} = {value!r}: {bad[0]!r} is not allowed; each entry must "
                              f"be {f.allowed()}")
        return list(value)
    if not all(isinstance(p, list) and len(p) == 2 and all(_is_num(v) for v in p)
               for p in value):
        raise ConfigError(f"{name} = {value!r}: must be a list of [r_mm, z_mm] pairs of finite "
                          f"numbers")
    return [[float(a), float(b)] for a, b in value]


def _cross_checks(raw: dict, out: dict) -> None:
    """Rules that involve several keys."""
    if "membrane" in out:
        _membrane_checks(out)
        return
    if "block" in out:
        b = out["block"]
        for fine, full in (("fine_width_mm", "width_mm"), ("fine_depth_mm", "depth_mm")):
            if b[fine] > b[full]:
                raise ConfigError(f"block.{fine} = {b[fine]!r}: must be <= block.{full} = "
                                  f"{b[full]!r}")
    if out["die"]["reduction"] is None:
        f = SCHEMA["die"]["reduction"]
        raise ConfigError(f"missing required key die.reduction (float in {f.allowed()}): {f.doc}")
    if "ring" in out:
        r = out["ring"]
        if r["inner_diameter_mm"] >= r["outer_diameter_mm"]:
            raise ConfigError(f"ring.inner_diameter_mm = {r['inner_diameter_mm']!r}: must be "
                              f"< ring.outer_diameter_mm = {r['outer_diameter_mm']!r}")
    d = out["die"]
    if len(d["path_time_s"]) != len(d["path_travel_mm"]):
        raise ConfigError("die.path_time_s and die.path_travel_mm must have the same length")
    if d["path_time_s"]:
        t, s = d["path_time_s"], d["path_travel_mm"]
        if len(t) < 2 or t[0] != 0.0 or s[0] != 0.0:
            raise ConfigError("die.path_time_s / die.path_travel_mm: at least 2 rows, starting "
                              "at time 0 s with travel 0 mm")
        if any(b <= a for a, b in zip(t, t[1:])) or any(b < a for a, b in zip(s, s[1:])):
            raise ConfigError("die.path_time_s must increase and die.path_travel_mm must not "
                              "decrease")
    elif d["speed_mm_s"] is None:
        f = SCHEMA["die"]["speed_mm_s"]
        raise ConfigError(f"missing required key die.speed_mm_s (float in {f.allowed()}): "
                          f"{f.doc}")
    if d["profile_mm"] and len(d["profile_mm"]) < 2:
        raise ConfigError("die.profile_mm: needs at least 2 [r_mm, z_mm] points (or [] for a "
                          "flat die)")
    if out["mesh"]["rezone_quality"] > 0.0 and out["mesh"]["file"]:
        raise ConfigError("mesh.rezone_quality > 0 needs the structured mesh (mesh.file = ''): "
                          "rezoning relocates the nodes of the logical grid")
    fr = out["friction"]
    if fr["model"] == "coulomb" and "mu" not in raw.get("friction", {}):
        raise ConfigError("friction.model = 'coulomb' needs friction.mu (float in [0, 10])")
    if fr["model"] == "shear" and "m" not in raw.get("friction", {}):
        raise ConfigError("friction.model = 'shear' needs friction.m (float in [0, 1])")


def _membrane_checks(out: dict) -> None:
    m, ld = out["membrane"], out["load"]
    if out["mesh"]["geometry"] != "plane_strain":
        raise ConfigError(f"mesh.geometry = {out['mesh']['geometry']!r}: a [membrane] scene is "
                          f"plane strain; set mesh.geometry = 'plane_strain'")
    c = m["corners_mm"]
    if len(c) != 4:
        raise ConfigError(f"membrane.corners_mm: needs exactly 4 [x_mm, y_mm] corners, got "
                          f"{len(c)}")
    turns = []
    for i in range(4):
        (x0, y0), (x1, y1), (x2, y2) = c[i], c[(i + 1) % 4], c[(i + 2) % 4]
        turns.append((x1 - x0) * (y2 - y1) - (y1 - y0) * (x2 - x1))
    if min(turns) <= 0.0:
        raise ConfigError(f"membrane.corners_mm = {c!r}: the corners must form a convex "
                          f"quadrilateral, listed counter-clockwise")
    if m["tip_mm"] and len(m["tip_mm"]) != 2:
        raise ConfigError(f"membrane.tip_mm = {m['tip_mm']!r}: must be [x_mm, y_mm] or []")
    if ld["edge"] == m["clamped_edge"]:
        raise ConfigError(f"load.edge = {ld['edge']!r}: must differ from membrane.clamped_edge")
    for key in ("force_x_N", "force_y_N"):
        if not math.isfinite(ld[key]):
            raise ConfigError(f"load.{key} = {ld[key]!r}: must be finite")
    if ld["force_x_N"] == 0.0 and ld["force_y_N"] == 0.0:
        raise ConfigError("load.force_x_N and load.force_y_N are both 0: give the load's "
                          "resultant (N per mm of depth)")


# keys that may be left out even though they have no default (checked in _cross_checks)
_CONDITIONAL = {("die", "speed_mm_s"), ("die", "reduction")}


def load_config(path_or_dict: str | PathLike | dict, overrides: Iterable[str] = ()) -> dict:
    """Read a TOML scene (path) or nested dict, apply ``section.key=value`` overrides,
    validate, and return a new nested dict with every schema key (defaults filled in)."""
    if isinstance(path_or_dict, dict):
        raw = copy.deepcopy(path_or_dict)
    else:
        try:
            raw = tomllib.loads(Path(path_or_dict).read_text())
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{path_or_dict}: invalid TOML: {exc}") from exc
    for text in overrides:
        section, key, value = _parse_override(text)
        sec = raw.setdefault(section, {})
        if not isinstance(sec, dict):
            raise ConfigError(f"{section}: must be a table of keys, not {sec!r}")
        sec[key] = value
    for section, table in raw.items():
        if section not in SCHEMA:
            raise ConfigError(f"unknown section {section!r}; allowed sections: "
                              f"{', '.join(SCHEMA)}")
        if not isinstance(table, dict):
            raise ConfigError(f"{section}: must be a table of keys "
                              f"({', '.join(SCHEMA[section])}), not {table!r}")
        for key in table:
            if key not in SCHEMA[section]:
                raise ConfigError(f"unknown key {section}.{key}; allowed keys of [{section}]: "
                                  f"{', '.join(SCHEMA[section])}")
    kind = _workpiece(raw)
    for section in raw:
        if not _applies(section, kind):
            raise ConfigError(f"[{section}] does not apply to a [{kind}] scene; allowed sections: "
                              f"{', '.join(s for s in SCHEMA if _applies(s, kind))}")
    out: dict[str, dict[str, Any]] = {}
    for section, fields in SCHEMA.items():
        if not _applies(section, kind):
            continue
        given = raw.get(section, {})
        out[section] = {}
        for key, f in fields.items():
            name = f"{section}.{key}"
            if key in given:
                out[section][key] = _check(name, f, given[key])
            elif f.default is None and (section, key) not in _CONDITIONAL:
                raise ConfigError(f"missing required key {name} ({f.kind} in {f.allowed()}): "
                                  f"{f.doc}")
            else:
                out[section][key] = copy.deepcopy(f.default)
    _cross_checks(raw, out)
    return out


def dump_config(cfg: dict, path: str | PathLike) -> None:
    """Write a (resolved) config as TOML (keys whose value is unset are left out)."""
    clean = {s: {k: v for k, v in t.items() if v is not None} for s, t in cfg.items()}
    Path(path).write_bytes(tomli_w.dumps(clean).encode())


def describe_schema() -> str:
    """A Markdown table (key | type | default | allowed | meaning) of every key."""
    rows = ["| key | type | default | allowed | meaning |", "|---|---|---|---|---|"]
    for section, fields in SCHEMA.items():
        for key, f in fields.items():
            if f.default is None:
                default = "required"
            elif f.kind == "bool":
                default = str(f.default).lower()
            elif f.kind == "str":
                default = f'"{f.default}"'
            elif f.kind in ("floats", "strs", "points"):
                default = "[" + ", ".join(f'"{v}"' if isinstance(v, str) else f"{v:g}"
                                          for v in f.default) + "]"
            else:
                default = f"{f.default:g}" if f.kind == "float" else str(f.default)
            cells = [f"`{section}.{key}`", f.kind, default, f.allowed(), f.doc]
            rows.append("| " + " | ".join(c.replace("|", r"\|") for c in cells) + " |")
    return "\n".join(rows) + "\n"
