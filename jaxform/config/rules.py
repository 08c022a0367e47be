"""The rules that involve several keys, run on the typed sections of a document whose
keys each passed their own check (:func:`check_document`).  Grouped by what they
check: heat, wear, mesh and remeshing, the workpiece's shape, the dies' motion, the
press, the bottom and side dies, friction, and the run's size.  Each refusal is one
line naming the keys and what is allowed.  This module imports no JAX."""

from __future__ import annotations

import math
from pathlib import Path

from jaxform.config.die_sections import FRICTION_COEFFICIENT, FRICTION_DIES
from jaxform.config.document import SCHEMA, Config, thaw
from jaxform.config.schema import MAX_ELEMENTS, MAX_STEPS
from jaxform.config.stroke import closing_time
from jaxform.errors import ConfigError


def check_document(cfg: Config, raw: dict) -> None:
    """Every cross-key rule of a typed document; ``raw`` is the document as written (with
    its overrides), for the rules that ask whether a key was given at all."""
    _heat_rules(cfg)
    _wear_rules(cfg)
    _remesh_rules(cfg)
    if cfg.membrane is not None:
        _membrane_rules(cfg)
    else:
        _shape_rules(cfg)
        _die_motion_rules(cfg)
        _press_rules(cfg)
        _mesh_rules(cfg)
        if cfg.billet is not None or cfg.ring is not None:
            _die_set_rules(cfg, raw)
        _friction_rules(cfg, raw)
    _size_rules(cfg)


def _required(section: str, key: str) -> ConfigError:
    """The refusal of a required key left out."""
    f = SCHEMA[section][key]
    return ConfigError(f"missing required key {section}.{key} ({f.kind} in {f.allowed()}): {f.doc}")


# ----------------------------------------------------------------------------------
# heat, wear, mesh and remeshing


def _heat_rules(cfg: Config) -> None:
    """A coupled run has the material's thermal properties; a dwell needs heat; the die
    temperature path is a table from 0 s."""
    mat, th = cfg.material, cfg.thermal
    keys = ("density_kg_m3", "specific_heat_J_kgK", "conductivity_W_mK")
    missing = [k for k in keys if getattr(mat, k) is None]
    if th.model == "coupled" and missing:
        raise ConfigError(
            f"thermal.model = 'coupled' needs material.{missing[0]}: the preset "
            f"{mat.preset!r} has no [thermal] table; give "
            + ", ".join(f"material.{k}" for k in missing)
        )
    if th.dwell_s > 0.0 and th.model != "coupled":
        raise ConfigError("thermal.dwell_s > 0 needs thermal.model = 'coupled'")
    times, change = th.die_path_time_s, th.die_path_change_K
    if len(times) != len(change):
        raise ConfigError(
            "thermal.die_path_time_s and thermal.die_path_change_K must have the same length"
        )
    if times and (times[0] != 0.0 or any(b <= a for a, b in zip(times, times[1:]))):
        raise ConfigError("thermal.die_path_time_s: must start at 0 s and increase")


def _wear_rules(cfg: Config) -> None:
    wear = cfg.wear
    if wear is not None and any(not v > 0.0 or v > 1e5 for v in wear.hardness_by_die_MPa):
        raise ConfigError("wear.hardness_by_die_MPa: every entry must lie in (0, 100000] MPa")


def _remesh_rules(cfg: Config) -> None:
    """Remeshing excludes rezoning and a membrane (whose load is per initial edge); its
    start mesh needs a trigger."""
    if not cfg.remesh.on:
        if cfg.remesh.from_start:
            raise ConfigError(
                "remesh.from_start = true needs a remesh trigger (e.g. remesh.quality_below "
                "in (0, 1)): a run that never remeshes keeps its structured mesh"
            )
        return
    if cfg.mesh.rezone_quality > 0.0:
        raise ConfigError(
            "mesh.rezone_quality > 0 and [remesh] both set: choose one (remeshing "
            "replaces the mesh, rezoning moves its nodes); set mesh.rezone_quality = 0"
        )
    if cfg.membrane is not None:
        raise ConfigError(
            "[remesh]: a [membrane] scene cannot be remeshed (its load is given per "
            f"initial edge); set {cfg.remesh.off_keys}"
        )


def _mesh_rules(cfg: Config) -> None:
    """Rezoning moves the nodes of the structured grid; a mesh file exists."""
    m = cfg.mesh
    if m.rezone_quality > 0.0 and m.file:
        raise ConfigError(
            "mesh.rezone_quality > 0 needs the structured mesh (mesh.file = ''): "
            "rezoning relocates the nodes of the logical grid"
        )
    if m.file and not Path(m.file).is_file():
        raise ConfigError(f"mesh.file = {m.file!r}: no such file")


# ----------------------------------------------------------------------------------
# the workpiece's shape


def _shape_rules(cfg: Config) -> None:
    """A block's fine zone lies inside it; a ring's bore inside its outer diameter."""
    b = cfg.block
    if b is not None:
        for fine, full in (("fine_width_mm", "width_mm"), ("fine_depth_mm", "depth_mm")):
            if getattr(b, fine) > getattr(b, full):
                raise ConfigError(
                    f"block.{fine} = {getattr(b, fine)!r}: must be <= block.{full} = "
                    f"{getattr(b, full)!r}"
                )
    r = cfg.ring
    if r is not None and r.inner_diameter_mm >= r.outer_diameter_mm:
        raise ConfigError(
            f"ring.inner_diameter_mm = {r.inner_diameter_mm!r}: must be "
            f"< ring.outer_diameter_mm = {r.outer_diameter_mm!r}"
        )


def _membrane_rules(cfg: Config) -> None:
    """A membrane is a convex plane-strain quadrilateral, loaded on an unclamped edge."""
    m, ld = cfg.membrane, cfg.load
    if cfg.mesh.geometry != "plane_strain":
        raise ConfigError(
            f"mesh.geometry = {cfg.mesh.geometry!r}: a [membrane] scene is "
            f"plane strain; set mesh.geometry = 'plane_strain'"
        )
    c = thaw(m.corners_mm)
    if len(c) != 4:
        raise ConfigError(
            f"membrane.corners_mm: needs exactly 4 [x_mm, y_mm] corners, got {len(c)}"
        )
    turns = []
    for i in range(4):
        (x0, y0), (x1, y1), (x2, y2) = c[i], c[(i + 1) % 4], c[(i + 2) % 4]
        turns.append((x1 - x0) * (y2 - y1) - (y1 - y0) * (x2 - x1))
    if min(turns) <= 0.0:
        raise ConfigError(
            f"membrane.corners_mm = {c!r}: the corners must form a convex "
            f"quadrilateral, listed counter-clockwise"
        )
    if m.tip_mm and len(m.tip_mm) != 2:
        raise ConfigError(f"membrane.tip_mm = {thaw(m.tip_mm)!r}: must be [x_mm, y_mm] or []")
    if ld.edge == m.clamped_edge:
        raise ConfigError(f"load.edge = {ld.edge!r}: must differ from membrane.clamped_edge")
    for key in ("force_x_N", "force_y_N"):
        if not math.isfinite(getattr(ld, key)):
            raise ConfigError(f"load.{key} = {getattr(ld, key)!r}: must be finite")
    if ld.force_x_N == 0.0 and ld.force_y_N == 0.0:
        raise ConfigError(
            "load.force_x_N and load.force_y_N are both 0: give the load's "
            "resultant (N per mm of depth)"
        )


# ----------------------------------------------------------------------------------
# the dies: motion, press, bottom and side dies, friction


def _die_motion_rules(cfg: Config) -> None:
    """The top die's stroke, path table or speed, profile and flash land."""
    d, model = cfg.die, cfg.press.model
    if d.reduction is None and model not in ("screw", "hammer"):
        raise _required("die", "reduction")
    _check_path("die", d, monotone=True)
    if not d.path_time_s and d.speed_mm_s is None and model == "speed":
        raise _required("die", "speed_mm_s")
    if d.profile_mm and len(d.profile_mm) < 2:
        raise ConfigError(
            "die.profile_mm: needs at least 2 [r_mm, z_mm] points (or [] for a flat die)"
        )
    if d.part_radius_mm > 0.0 and not d.closed:
        raise ConfigError(
            f"die.part_radius_mm = {d.part_radius_mm!r}: needs die.closed = true "
            f"(it splits a closed die's cavity into the part and the flash land)"
        )


def _check_path(section: str, d, monotone: bool) -> None:
    """A path table ``section.path_time_s`` -> ``section.path_travel_mm``: same lengths,
    at least 2 rows from (0 s, 0 mm), times increasing (travel not decreasing if
    ``monotone``); an empty table passes."""
    t, s = d.path_time_s, d.path_travel_mm
    if len(t) != len(s):
        raise ConfigError(
            f"{section}.path_time_s and {section}.path_travel_mm must have the same length"
        )
    if not t:
        return
    if len(t) < 2 or t[0] != 0.0 or s[0] != 0.0:
        raise ConfigError(
            f"{section}.path_time_s / {section}.path_travel_mm: at least 2 rows, starting "
            "at time 0 s with travel 0 mm"
        )
    if any(b <= a for a, b in zip(t, t[1:])):
        raise ConfigError(f"{section}.path_time_s must increase")
    if monotone and any(b < a for a, b in zip(s, s[1:])):
        raise ConfigError(f"{section}.path_travel_mm must not decrease")


def _press_rules(cfg: Config) -> None:
    """[press]: a machine other than 'speed' drives the top die alone (no path table, no
    shared bottom-die speed); a screw press makes one stroke; energy presses do not dwell
    and keep one mesh."""
    pr, d = cfg.press, cfg.die
    model = pr.model
    if model == "speed":
        return
    if d.path_time_s:
        raise ConfigError(
            f"press.model = {model!r} moves the die itself: set die.path_time_s = [] "
            "(path tables belong to press.model = 'speed')"
        )
    if cfg.bottom_die is not None and cfg.bottom_die.speed_share > 0.0:
        raise ConfigError(
            f"bottom_die.speed_share > 0 needs press.model = 'speed' (a {model} press "
            "drives the top die; the bottom die stands)"
        )
    if model == "crank" and pr.rod_length_mm <= 0.5 * pr.stroke_mm:
        raise ConfigError(
            f"press.rod_length_mm = {pr.rod_length_mm!r}: must be > press.stroke_mm / 2 = "
            f"{0.5 * pr.stroke_mm!r} (the connecting rod must be longer than the crank)"
        )
    if model == "screw" and pr.blows != 1:
        raise ConfigError(f"press.blows = {pr.blows!r}: a screw press makes one stroke (1)")
    energy = model in ("screw", "hammer")
    if energy and (cfg.remesh.on or cfg.mesh.rezone_quality > 0.0):
        raise ConfigError(
            f"press.model = {model!r}: its blows run on one mesh; set mesh.rezone_quality "
            f"= 0 and leave [remesh] off ({cfg.remesh.off_keys})"
        )
    if energy and cfg.thermal.dwell_s > 0.0:
        raise ConfigError(
            f"thermal.dwell_s > 0 needs press.model = 'speed' or 'crank' (a {model} "
            "starts at its blow)"
        )


def _die_set_rules(cfg: Config, raw: dict) -> None:
    """The bottom and side dies of a billet or ring scene."""
    kind = cfg.workpiece
    full = getattr(cfg, kind).full_height
    sd = cfg.side_die
    given = {k for k, v in raw.get("bottom_die", {}).items()
             if v != SCHEMA["bottom_die"][k].default}  # fmt: skip
    if given and not full:
        raise ConfigError(
            f"bottom_die.{sorted(given)[0]}: a bottom die needs {kind}.full_height = true "
            "(a half-height model stands on its mid-plane, z = 0)"
        )
    if full:
        _full_height_rules(cfg)
    if sd.profile_mm and len(sd.profile_mm) < 2:
        raise ConfigError("side_die.profile_mm: needs at least 2 [r_mm, z_mm] points")
    _check_path("side_die", sd, monotone=False)
    if sd.path_time_s and not sd.profile_mm:
        raise ConfigError("side_die.path_time_s: needs side_die.profile_mm (no side die is set)")


def _full_height_rules(cfg: Config) -> None:
    """A full-height scene's bottom die: its profile or the top die's mirrored, its path
    table beside the top die's, or its share of the ram speed; no rezoning."""
    bd, d = cfg.bottom_die, cfg.die
    if bd.mirror and bd.profile_mm:
        raise ConfigError(
            "bottom_die.mirror = true takes the top die's profile: set bottom_die.profile_mm = []"
        )
    if bd.profile_mm and len(bd.profile_mm) < 2:
        raise ConfigError("bottom_die.profile_mm: needs at least 2 [r_mm, z_mm] points")
    _check_path("bottom_die", bd, monotone=True)
    if bd.path_time_s and not d.path_time_s:
        raise ConfigError(
            "bottom_die.path_time_s needs die.path_time_s (both dies on path tables); "
            "with die.speed_mm_s use bottom_die.speed_share"
        )
    if bd.speed_share > 0.0 and d.path_time_s:
        raise ConfigError(
            f"bottom_die.speed_share = {bd.speed_share!r} shares die.speed_mm_s: with "
            "die.path_time_s give the bottom die's own bottom_die.path_time_s instead"
        )
    if cfg.mesh.rezone_quality > 0.0:
        raise ConfigError(
            f"mesh.rezone_quality > 0 needs a half-height model ({cfg.workpiece}.full_height "
            "= false): use [remesh] for a full-height one"
        )


def _friction_rules(cfg: Config, raw: dict) -> None:
    """A law with a coefficient has it given (in the die's own table or in [friction]);
    a die's own table belongs to a die the scene has."""
    need = FRICTION_COEFFICIENT
    model, written = cfg.friction.model, raw.get("friction", {})
    if model in need and need[model] not in written:
        k = need[model]
        f = SCHEMA["friction"][k]
        raise ConfigError(f"friction.model = {model!r} needs friction.{k} ({f.kind} in "
                          f"{f.allowed()})")  # fmt: skip
    dies = cfg.die_sections()
    for die in FRICTION_DIES:
        own = {k: v for k, v in raw.get(f"{die}.friction", {}).items() if v is not None}
        if own and die not in dies:
            raise ConfigError(
                f"{die}.friction.{sorted(own)[0]}: the scene has no {die} (a bottom die needs "
                "full_height = true, a side die side_die.profile_mm)"
            )
        law = cfg.friction_of(die).model
        k = need.get(law)
        if own and k and k not in own and k not in written:
            raise ConfigError(
                f"{die}.friction.model = {law!r} needs {die}.friction.{k} or friction.{k} "
                f"(float in {SCHEMA['friction'][k].allowed()})"
            )


# ----------------------------------------------------------------------------------
# the run's size


def _size_rules(cfg: Config) -> None:
    """The mesh and the step count within MAX_ELEMENTS and MAX_STEPS; the design's start
    within its bounds."""
    m = cfg.mesh
    if m.nr * m.nz > MAX_ELEMENTS:
        raise ConfigError(
            f"mesh.nr x mesh.nz = {m.nr} x {m.nz} = {m.nr * m.nz} "
            f"elements: at most {MAX_ELEMENTS} fit a run; use a coarser mesh"
        )
    t_end, what = end_time(cfg)
    dt = cfg.time.dt_s
    if t_end is not None and t_end / dt > MAX_STEPS:
        raise ConfigError(
            f"time.dt_s = {dt!r}: the run to {t_end:.6g} s ({what}) would take "
            f"{t_end / dt:.3g} steps, at most {MAX_STEPS}: raise time.dt_s or "
            f"shorten the run"
        )
    if t_end is not None and t_end / dt <= 1e-9:  # jaxform.scenes.Scene.n_steps: 0 steps
        raise ConfigError(
            f"time.dt_s = {dt!r}: the run to {t_end:.6g} s ({what}) would take no "
            f"step; give time.dt_s <= {t_end:.6g}"
        )
    d = cfg.design
    lo, hi = 1.0 / d.bound_factor, d.bound_factor
    if not lo <= d.material_start_factor <= hi:
        raise ConfigError(
            f"design.material_start_factor = {d.material_start_factor!r}: must "
            f"lie in [1/design.bound_factor, design.bound_factor] = "
            f"[{lo:.6g}, {hi:.6g}]"
        )


def end_time(cfg: Config) -> tuple[float | None, str]:
    """(end time of the run in s, the keys that set it), or (None, '') where it is not
    known before the mesh is built (a mesh file sets the height; a press other than
    'speed' sets the motion) or the path table never reaches the stroke (refused when
    the scene is built).  The dies' part is :func:`jaxform.config.stroke.closing_time`,
    which the scene runs on the mesh's height."""
    if cfg.membrane is not None:
        return cfg.load.ramp_time_s, "load.ramp_time_s"
    if cfg.mesh.file or cfg.press.model != "speed":
        return None, ""
    kind = cfg.workpiece
    name = "depth_mm" if kind == "block" else "height_mm"
    height = getattr(getattr(cfg, kind), name)
    full = kind == "block" or getattr(cfg, kind).full_height
    share = 1.0 if full else 0.5  # the moving die's share of the ram travel and speed
    bottom = cfg.bottom_die if full and kind != "block" else None
    try:
        t_end = closing_time(cfg.die, bottom, cfg.die.reduction * height * share, share)
    except ConfigError:
        return None, ""
    if cfg.die.path_time_s:
        return t_end, f"die.path_time_s to die.reduction x {kind}.{name}"
    return t_end, f"die.reduction x {kind}.{name} / die.speed_mm_s"
