"""What each design group and each design objective needs of a scene, declared beside
their names, and the one check of a gradient run (jaxform design, taylor-test, a study
with gradients) against a typed config (:class:`jaxform.config.Config`) before anything
is built.

A requirement is a function of the typed config that returns None where it holds, or
the phrase a refusal puts after ``needs`` (the keys to set and what they are now).  The
config's choices of ``design.variables`` and ``design.objective`` are the names here.
This module imports no JAX (the config layer reads it)."""

from __future__ import annotations

import csv
import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from jaxform.errors import ConfigError

if TYPE_CHECKING:
    from jaxform.config import Config

Requirement = Callable[["Config"], "str | None"]


@dataclass(frozen=True)
class GroupSpec:
    """A design variable group: what it varies and what the scene needs for it (checked
    in order; the first unmet one is reported)."""

    doc: str
    requires: tuple[Requirement, ...] = ()


@dataclass(frozen=True)
class ObjectiveSpec:
    """A design objective: what it measures, what the scene needs for it, the columns it
    reads from design.target_csv (none: it takes no target), and whether it reads only
    the force history and the state carried through remeshes (so it has a gradient
    through them)."""

    doc: str
    requires: tuple[Requirement, ...] = ()
    target_columns: tuple[str, ...] = ()
    through_remeshes: bool = False


# ----------------------------------------------------------------------------------
# requirements of the groups


def _a_die(cfg: Config) -> str | None:
    return "a die; a [membrane] scene has none" if cfg.membrane is not None else None


def _differentiable_friction(cfg: Config) -> str | None:
    """Some die's friction law with a coefficient, Coulomb's mu or the shear factor m (its
    own [<die>.friction] model, else [friction]'s)."""
    if any(cfg.friction_of(die).model in ("coulomb", "shear") for die in cfg.die_sections()):
        return None
    return (
        f"friction.model = 'coulomb' or 'shear', not {cfg.friction.model!r} (or a die's own "
        "[<die>.friction] model)"
    )


def _the_speed_press(cfg: Config) -> str | None:
    model = cfg.press.model
    if model == "speed":
        return None
    return f"press.model = 'speed' (a {model} press sets its own speed)"


def _a_ram_speed(cfg: Config) -> str | None:
    if not cfg.die.path_time_s:
        return None
    return "die.speed_mm_s; this scene moves the die along die.path_time_s"


def _a_structured_billet(cfg: Config) -> str | None:
    if cfg.billet is not None and not cfg.mesh.file:
        return None
    return "a [billet] scene on the structured mesh (mesh.file = '')"


def _heat_to_the_dies(cfg: Config) -> str | None:
    th = cfg.thermal
    if th.model == "coupled" and th.htc_die_W_m2K > 0.0:
        return None
    return "thermal.model = 'coupled' and thermal.htc_die_W_m2K > 0"


def _spline_controls(cfg: Config) -> str | None:
    n = cfg.design.die_spline_controls
    fixed = 2 if cfg.design.die_spline_fixed_ends else 0
    if n > 0 and n + fixed >= 4:
        return None
    return (f"design.die_spline_controls >= {4 - fixed} (the spline's free control heights; "
            f"now {n})")  # fmt: skip


def _a_process(cfg: Config) -> str | None:
    """Groups that only a process has (its billet before the first blow, its dwells)."""
    return "a process ([[process.operation]] tables)"


# every design group, in the order problems list them
GROUPS: dict[str, GroupSpec] = {
    "material": GroupSpec("the law's parameters (design.material_params), log-scaled"),
    "friction": GroupSpec("the friction coefficient (mu or m)", (_a_die, _differentiable_friction)),
    "speed": GroupSpec("the ram speed, log-scaled", (_a_die, _the_speed_press, _a_ram_speed)),
    "preform": GroupSpec("cosine modes of the billet's side", (_a_structured_billet,)),
    "nodes": GroupSpec("every free initial node coordinate"),
    "die": GroupSpec("vertical offsets of the top die's profile points", (_a_die,)),
    "die_spline": GroupSpec(
        "control heights of a cubic B-spline of the top die's profile between two radii",
        (_a_die, _spline_controls),
    ),
    "thermal": GroupSpec(
        "temperatures, die contact conductance, Taylor-Quinney factor", (_heat_to_the_dies,)
    ),
    "billet": GroupSpec("the billet's height against its diameter at fixed volume", (_a_process,)),
    "billet_volume": GroupSpec("the billet's volume at fixed aspect, log-scaled", (_a_process,)),
    "dwell": GroupSpec("a dwell's (furnace's) time, log-scaled", (_a_process,)),
}
# a process's groups: those that act on one operation's inputs (named <operation>.<group>
# or, with design.operation, by the group alone) and those that act on the process (the
# first mesh, or every operation alike; thermal: every operation, or one if named)
OPERATION_GROUPS = ("die", "die_spline", "friction", "speed", "thermal", "dwell")
PROCESS_GROUPS = ("preform", "nodes", "billet", "billet_volume", "material", "thermal")
# the objectives of a process (of one operation's run: design.objective_operation)
PROCESS_OBJECTIVES = ("peak_force", "forging_work", "press_capacity", "flash_volume",
                      "die_fill", "lap", "mean_temperature")  # fmt: skip
# a process's weighted sum: design.terms of design.objective_operation and
# design.operation_terms ('<operation>.<objective>'), weighted by design.term_weights
PROCESS_WEIGHTED_SUM = "weighted_sum"


# ----------------------------------------------------------------------------------
# requirements of the objectives


def _a_closed_die(cfg: Config) -> str | None:
    return None if cfg.die is not None and cfg.die.closed else "die.closed = true"


def _wear(cfg: Config) -> str | None:
    return None if cfg.wear is not None and cfg.wear.on else "wear.on = true"


def _a_free_side(cfg: Config) -> str | None:
    if cfg.billet is not None or cfg.ring is not None:
        return None
    return "a [billet] or [ring] scene (a free side)"


def _coupled(cfg: Config) -> str | None:
    return None if cfg.thermal.model == "coupled" else "thermal.model = 'coupled'"


def part_radius(cfg: Config) -> str | None:
    if cfg.die is not None and cfg.die.part_radius_mm > 0.0:
        return None
    return "die.part_radius_mm > 0 (a closed die's part, the flash land beyond it)"


def _a_flash_radius(cfg: Config) -> str | None:
    if cfg.design.flash_radius_mm > 0.0 or (cfg.die is not None and cfg.die.part_radius_mm > 0.0):
        return None
    return "design.flash_radius_mm > 0 or die.part_radius_mm > 0 (the radius the flash lies beyond)"


def _a_capacity(cfg: Config) -> str | None:
    return None if cfg.design.press_capacity_N > 0.0 else "design.press_capacity_N > 0"


def _a_free_surface(cfg: Config) -> str | None:
    if cfg.membrane is None and not cfg.mesh.file:
        return None
    return "a die scene on the structured mesh (its free surface is the contact sets)"


def _terms(cfg: Config) -> str | None:
    d = cfg.design
    if d.terms and len(d.terms) == len(d.term_weights):
        return None
    return (f"design.terms (now {list(d.terms)}) and as many design.term_weights "
            f"(now {list(d.term_weights)})")  # fmt: skip


OBJECTIVES: dict[str, ObjectiveSpec] = {
    "forging_work": ObjectiveSpec("force integral over stroke (N mm)", through_remeshes=True),
    "peak_force": ObjectiveSpec("peak ram force (N)", through_remeshes=True),
    "side_straightness": ObjectiveSpec(
        "mean squared deviation of the final side from straight (mm^2)", (_a_free_side,)
    ),
    "shape_target": ObjectiveSpec(
        "mean squared deviation of chosen nodes from target positions (mm^2)",
        target_columns=("node", "r_mm", "z_mm"),
    ),
    "force_misfit": ObjectiveSpec(
        "force-stroke misfit against a target curve",
        target_columns=("stroke_mm", "force_N"),
        through_remeshes=True,
    ),
    "eqps_spread": ObjectiveSpec("variance of the equivalent plastic strain"),
    "die_fill": ObjectiveSpec("1 - die fill", (_a_closed_die,)),
    "temperature_misfit": ObjectiveSpec(
        "mean squared misfit of the mean temperature history (K^2)",
        (_coupled,),
        target_columns=("time_s", "mean_temperature_K"),
    ),
    "mean_temperature": ObjectiveSpec("mean temperature at the end (K)", (_coupled,)),
    "max_damage": ObjectiveSpec("smooth maximum of the damage at the end", through_remeshes=True),
    "wear_depth": ObjectiveSpec(
        "smooth maximum of the die wear depth (mm)", (_wear,), through_remeshes=True
    ),
    "flash_volume": ObjectiveSpec(
        "material beyond design.flash_radius_mm at the end (mm^3)", (_a_die, _a_flash_radius)
    ),
    "press_capacity": ObjectiveSpec(
        "penalty on the peak force above design.press_capacity_N",
        (_a_die, _a_capacity),
        through_remeshes=True,
    ),
    "lap": ObjectiveSpec(
        "penalty on free-surface wedges narrower than design.lap_angle_deg at the end",
        (_a_die, _a_free_surface),
    ),
    "weighted_sum": ObjectiveSpec(
        "sum of design.term_weights x design.terms (each term's value in the report)", (_terms,)
    ),
}


def objective_names(cfg: Config) -> tuple[str, ...]:
    """The objectives the config's design.objective evaluates: itself, or the terms of a
    weighted sum."""
    d = cfg.design
    return tuple(d.terms) if d.objective == "weighted_sum" else (d.objective,)


def through_remeshes(cfg: Config) -> bool:
    """Whether every objective the config evaluates has a gradient through remeshes."""
    return all(OBJECTIVES[n].through_remeshes for n in objective_names(cfg))


# ----------------------------------------------------------------------------------
# the checks


def unmet_group(cfg: Config, name: str) -> str | None:
    """The first requirement of design group ``name`` that ``cfg`` does not meet, as the
    phrase after ``needs``; None where it meets them all."""
    return next((r for need in GROUPS[name].requires if (r := need(cfg)) is not None), None)


def check_groups(cfg: Config, groups: Iterable[str], where: str) -> None:
    """Refuse design groups that are unknown or that the scene cannot vary (``where``
    names the key or flag that asked for them); an energy press (screw, hammer) has no
    gradient run of its kind."""
    groups = list(groups)
    shown = (
        f"{where} = {groups!r}" if where.startswith("design.") else f"{where} {' '.join(groups)}"
    )
    if not groups:
        raise ConfigError(f"{shown}: name at least one design group, of {', '.join(GROUPS)}")
    for g in groups:
        if g not in GROUPS:
            raise ConfigError(
                f"{shown}: {g!r} is not a design group; each must be one of {', '.join(GROUPS)}"
            )
    model = cfg.press.model if cfg.press is not None else "speed"
    if model in ("screw", "hammer"):
        raise ConfigError(
            f"press.model = {model!r}: design and taylor-test run presses that follow "
            "time ('speed', 'crank'); differentiate blows with jaxform.blows.blow_run"
        )
    for g in groups:
        reason = unmet_group(cfg, g)
        if reason is not None:
            raise ConfigError(f"{shown}: {g!r} needs {reason}")


def check_objective(cfg: Config) -> None:
    """Refuse a design objective (and a temperature limit) whose inputs the scene lacks:
    its requirements, and for an objective with a target a readable design.target_csv
    with its columns."""
    d = cfg.design
    names = objective_names(cfg)
    for name in {d.objective, *names}:
        where = "design.objective =" if name == d.objective else "design.terms:"
        for need in OBJECTIVES[name].requires:
            reason = need(cfg)
            if reason is not None:
                raise ConfigError(f"{where} {name!r} needs {reason}")
    if d.max_temperature_K > 0.0 and _coupled(cfg) is not None:
        raise ConfigError("design.max_temperature_K > 0 needs thermal.model = 'coupled'")
    if d.objective == "weighted_sum" and any(w < 0.0 for w in d.term_weights):
        raise ConfigError(f"design.term_weights = {list(d.term_weights)}: must be >= 0")
    for name in names:
        columns = OBJECTIVES[name].target_columns
        if columns:
            if not d.target_csv:
                where = "design.objective =" if name == d.objective else "design.terms:"
                raise ConfigError(f"{where} {name!r} needs design.target_csv")
            _check_target_csv(d.target_csv, columns)


def check_gradient_run(
    cfg: Config, groups: Iterable[str] | None = None, where: str = "design.variables"
) -> None:
    """Refuse a typed config that a gradient run cannot use, before anything is built:
    rezoning, remeshing with an objective that reads the initial mesh, design groups the
    scene lacks (``groups``: the groups asked for, ``where`` names the key or flag that
    asked; None = not checked here), an objective whose inputs are missing."""
    q = cfg.mesh.rezone_quality
    if q > 0.0:
        raise ConfigError(
            f"mesh.rezone_quality = {q!r}: gradient runs need 0 (a rezoned "
            f"history has no gradient); --set mesh.rezone_quality=0"
        )
    d = cfg.design
    for k in ("operation", "objective_operation", "operation_variables", "operation_terms"):
        if getattr(d, k):
            raise ConfigError(
                f"design.{k} = {getattr(d, k)!r}: names an operation of a process "
                "([[process.operation]] tables); this config has none"
            )
    if cfg.remesh.on:
        if not through_remeshes(cfg):
            ok = ", ".join(n for n, o in OBJECTIVES.items() if o.through_remeshes)
            raise ConfigError(
                f"design.objective = {d.objective!r} reads the initial mesh's nodes or "
                f"elements, which a remeshed run replaces: with [remesh] use one of "
                f"{ok} (or set {cfg.remesh.off_keys})"
            )
        if d.max_temperature_K > 0.0:
            raise ConfigError(
                "design.max_temperature_K > 0 reads each row's nodal temperatures, which a "
                "remeshed run keeps on different meshes: set it to 0 with [remesh]"
            )
    if groups is not None:
        check_groups(cfg, groups, where)
    check_objective(cfg)


def _check_target_csv(path: str, needed: tuple[str, ...]) -> None:
    """The target CSV is a UTF-8 text file with the columns ``needed``, at least one row,
    and finite numbers in them."""
    where = f"design.target_csv = {path!r}"
    if not Path(path).is_file():
        raise ConfigError(f"{where}: no such file")
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            rows = list(csv.DictReader(fh))
    except OSError as exc:
        raise ConfigError(f"{where}: cannot read it: {exc.strerror or exc}") from exc
    except (UnicodeDecodeError, csv.Error) as exc:
        raise ConfigError(f"{where}: not a CSV text file ({exc})") from exc
    if not rows or any(k not in rows[0] for k in needed):
        raise ConfigError(
            f"{where}: needs a header with columns {', '.join(needed)} and at least one row"
        )
    for i, row in enumerate(rows, start=2):
        for k in needed:
            try:
                ok = math.isfinite(float(row[k]))
            except (TypeError, ValueError):
                ok = False
            if not ok:
                raise ConfigError(
                    f"{where}: line {i}, column {k} = {row[k]!r}: must be a finite number"
                )
