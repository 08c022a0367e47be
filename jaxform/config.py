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
import csv
import dataclasses
import math
import tomllib
from collections.abc import Iterable
from dataclasses import dataclass, replace
from os import PathLike
from pathlib import Path
from typing import Any

import tomli_w

from jaxform.errors import ConfigError
from jaxform.material_files import load_thermal_properties

__all__ = [
    "Config",
    "ConfigError",
    "SECTIONS",
    "typed",
    "Field",
    "SCHEMA",
    "load_config",
    "dump_config",
    "describe_schema",
    "check_design_run",
    "check_gradient_run",
    "MAX_STEPS",
    "MAX_ELEMENTS",
    "MAX_LENGTH_MM",
]

# Sizes a run can hold: beyond them a scene overflows the step schedule or the machine's
# memory, so it is refused up front with the keys that set it.
MAX_STEPS = 100_000  # load steps of one run (time to the end / time.dt_s)
MAX_ELEMENTS = 250_000  # mesh.nr x mesh.nz (e.g. 500 x 500)
# Every length (key ending in _mm) and speed (_mm_s) is at most this: a 1 km scene is
# already far outside forging, and 1e300 mm overflows the contact scale and the plots.
MAX_LENGTH_MM = 1e6
# the largest load resultant (N per mm of depth): stresses, energies and their squares stay
# far inside float64 (a resultant of 1e300 N overflows to inf in the strain energy)
MAX_FORCE_N = 1e12


@dataclass(frozen=True)
class Field:
    """One config key: kind, default (None = required), allowed range or choices, doc."""

    # "float" | "int" | "str" | "bool" | "floats" | "strs" (lists) | "points" (list of [a, b])
    kind: str
    default: Any = None
    low: float | None = None
    high: float | None = None
    low_inclusive: bool = True
    high_inclusive: bool = True
    choices: tuple[str, ...] | None = None
    doc: str = ""

    @property
    def numeric(self) -> bool:
        """A single number (float or int): what a study may vary."""
        return self.kind in ("float", "int")

    @property
    def integer(self) -> bool:
        return self.kind == "int"

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


# ----------------------------------------------------------------------------------
# The typed sections: one frozen dataclass per [section], one annotated attribute per
# key.  ``key(...)`` records the key's default (none: required), its allowed range or
# choices and its doc; the validator below reads them through SCHEMA, and
# :func:`typed` turns a validated document into these objects (lists become tuples).

_KINDS = {
    "float": "float",
    "float | None": "float",
    "int": "int",
    "str": "str",
    "str | None": "str",
    "bool": "bool",
    "tuple[float, ...]": "floats",
    "tuple[str, ...]": "strs",
    "tuple[tuple[float, float], ...]": "points",
}
SECTIONS: dict[str, type] = {}


def key(
    default: Any = None,
    *,
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
    high_open: bool = False,
    choices: tuple[str, ...] | None = None,
    doc: str = "",
):
    """A config key of a section class (default None: required)."""
    spec = dict(default=default, low=low, high=high, low_inclusive=not low_open,
                high_inclusive=not high_open, choices=choices, doc=doc)  # fmt: skip
    return dataclasses.field(metadata={"key": spec})


def section(name: str):
    """Register a section class under its TOML name."""

    def register(cls: type) -> type:
        SECTIONS[name] = cls
        return cls

    return register


FULL_HEIGHT_DOC = (
    "model the whole height, z in [-H/2, H/2], between the top die [die] and a bottom die "
    "[bottom_die] (no mid-plane; mesh.nz counts the elements over the whole height): for "
    "parts whose top and bottom differ. false: the half above the mid-plane z = 0"
)


def _profile_kind_key():
    return key(
        "polyline",
        choices=("polyline", "spline"),
        doc="straight segments between the points, or the Catmull-Rom spline through them",
    )


def _corner_radius_key(doc: str):
    return key(0.5, low=0.0, low_open=True, doc=doc)


@section("billet")
@dataclass(frozen=True, kw_only=True)
class BilletConfig:
    """[billet]: a solid cylinder (axisymmetric) or block (plane strain), half-height model
    (or full height, pressed between a top and a bottom die)."""

    diameter_mm: float = key(low=0.0, low_open=True, doc="billet diameter (mm)")
    height_mm: float = key(low=0.0, low_open=True, doc="billet height (mm)")
    full_height: bool = key(False, doc=FULL_HEIGHT_DOC)


@section("ring")
@dataclass(frozen=True, kw_only=True)
class RingConfig:
    """[ring]: a ring section, half-height model (or full height)."""

    outer_diameter_mm: float = key(low=0.0, low_open=True, doc="ring outer diameter (mm)")
    inner_diameter_mm: float = key(low=0.0, low_open=True, doc="ring inner diameter (mm), < outer")
    height_mm: float = key(low=0.0, low_open=True, doc="ring height (mm)")
    full_height: bool = key(False, doc=FULL_HEIGHT_DOC)


@section("block")
@dataclass(frozen=True, kw_only=True)
class BlockConfig:
    """[block]: a plane-strain block indented from the top (Prandtl's punch)."""

    width_mm: float = key(
        low=0.0,
        low_open=True,
        doc="plane-strain block for indentation: modelled half-width from the symmetry line x = 0"
        " (mm)",
    )
    depth_mm: float = key(
        low=0.0,
        low_open=True,
        doc="block depth (mm): frictionless support at y = 0, indented face at y = depth",
    )
    fine_width_mm: float = key(
        low=0.0,
        low_open=True,
        doc="width of the zone of equal elements at the indented face (mm), <= block.width_mm",
    )
    fine_depth_mm: float = key(
        low=0.0,
        low_open=True,
        doc="depth of the zone of equal elements below the indented face (mm), <= block.depth_mm",
    )
    growth: float = key(
        1.2,
        low=1.0,
        high=3.0,
        low_open=True,
        doc="size ratio of neighbouring elements outside the fine zone",
    )


@section("membrane")
@dataclass(frozen=True, kw_only=True)
class MembraneConfig:
    """[membrane]: a plane-strain panel with 4 straight edges (Cook's membrane), no die."""

    corners_mm: tuple[tuple[float, float], ...] = key(
        doc="the 4 corners [x_mm, y_mm] of a convex plane-strain panel, counter-clockwise; "
        "edges: bottom 1-2, right 2-3, top 3-4, left 4-1"
    )
    clamped_edge: str = key(
        "left", choices=("bottom", "right", "top", "left"), doc="edge with u = 0"
    )
    tip_mm: tuple[float, ...] = key(
        [],
        doc="[x_mm, y_mm] of the point whose displacement the history records as tip_ux_mm, "
        "tip_uy_mm (nearest node; [] = corner 3)",
    )


@section("load")
@dataclass(frozen=True, kw_only=True)
class LoadConfig:
    """[load]: the dead traction on a membrane edge."""

    edge: str = key(
        "right",
        choices=("bottom", "right", "top", "left"),
        doc="membrane edge carrying a uniform dead traction",
    )
    force_x_N: float = key(
        0.0,
        low=-MAX_FORCE_N,
        high=MAX_FORCE_N,
        doc="x-resultant of the traction (N per mm of depth), spread uniformly over the edge's "
        "initial length",
    )
    force_y_N: float = key(
        0.0,
        low=-MAX_FORCE_N,
        high=MAX_FORCE_N,
        doc="y-resultant of the traction (N per mm of depth), spread uniformly over the edge's "
        "initial length",
    )
    ramp_time_s: float = key(
        1.0,
        low=0.0,
        low_open=True,
        doc="the load grows linearly from 0 to full over this time (s); the run ends there",
    )


@section("mesh")
@dataclass(frozen=True, kw_only=True)
class MeshConfig:
    """[mesh]: element, geometry, resolution, mesh file and rezoning trigger."""

    nr: int = key(
        10,
        low=1,
        high=2000,
        doc="elements across the radius of the quarter section (block: across the fine zone; "
        "membrane: along edges bottom and top)",
    )
    nz: int = key(
        10,
        low=1,
        high=2000,
        doc="elements along the half height of the quarter section (block: down the fine zone; "
        "membrane: along edges left and right)",
    )
    element: str = key(
        "q1q1",
        choices=("q1q1", "q1p0", "q4"),
        doc="element formulation: stabilized mixed u-p (seed), mean-dilatation F-bar, plain "
        "displacement",
    )
    geometry: str = key(
        "axisymmetric",
        choices=("axisymmetric", "plane_strain"),
        doc="2-D idealization (plane strain: forces per mm of depth)",
    )
    stabilization: float = key(
        0.1,
        low=0.0,
        doc="q1q1 pressure stabilization theta in tau = theta h^2/(2 G_flow): G_flow is the "
        "elastic G where the material is elastic and sigma_eq/(3 d_eqps) where it flows "
        "(the thesis used 1e-4 with the elastic G)",
    )
    file: str = key(
        "",
        doc="optional gmsh/meshio quadrilateral mesh file replacing the structured mesh ('' = "
        "structured); line groups name the boundary sets (symmetry, top required; axis, side,"
        " inner, outer), point groups node sets (e.g. one axis node)",
    )
    rezone_quality: float = key(
        0.0,
        low=0.0,
        high=1.0,
        high_open=True,
        doc="rezone (relocate the nodes, carry the state over) after a step whose worst element "
        "corner quality (jaxform.rezone: 1 for squares) falls below this (0 = never; "
        "structured meshes only)",
    )


@section("remesh")
@dataclass(frozen=True, kw_only=True)
class RemeshConfig:
    """[remesh]: a new all-quad mesh of the deformed section (gmsh) when a trigger fires."""

    quality_below: float = key(
        0.0,
        low=0.0,
        high=1.0,
        high_open=True,
        doc="remesh after a step whose worst element corner quality (1 for squares, 0 for a "
        "degenerate corner) falls below this (0 = never; default 0.3 for a closed die "
        "whose config sets no remesh trigger and no mesh.rezone_quality, else 0)",
    )
    every_steps: int = key(
        0, low=0, high=100_000, doc="remesh after every this many converged steps (0 = never)"
    )
    element_size_mm: float = key(
        0.0,
        low=0.0,
        doc="element size of the new mesh in the bulk (mm; 0 = the initial mesh's mean "
        "element size)",
    )
    every_stroke_mm: float = key(
        0.0,
        low=0.0,
        doc="remesh after every this much ram stroke (mm) since the last mesh (0 = never)",
    )
    corner_depth_ratio: float = key(
        0.0,
        low=0.0,
        high=1.0,
        high_open=True,
        doc="remesh after a step where a convex die corner reaches into a free-surface facet "
        "deeper than this fraction of the facet's length (0 = never)",
    )
    fold_angle_deg: float = key(
        0.0,
        low=0.0,
        high=90.0,
        doc="remesh after a step where the free surface folds: a free vertex off the die "
        "whose air-side angle between its two edges falls below this (deg; 0 = never)",
    )
    elements_across: int = key(
        0,
        low=0,
        high=10,
        doc="the new mesh has at least this many elements across the section's local "
        "thickness (a flash, a thin web), down to a quarter of the die size (0 = off; "
        "default 3 for a closed die whose config sets no remesh trigger)",
    )
    onto_dies: bool = key(
        False,
        doc="the new mesh's nodes along the dies lie on the dies (gmsh adds them on the "
        "chords between contact nodes, off a concave arc or inside a convex one), the "
        "material volume kept by the free surface",
    )
    die_size_ratio: float = key(
        0.5,
        low=0.05,
        high=1.0,
        doc="element size where the workpiece touches a die and at sharp boundary corners, "
        "as a fraction of remesh.element_size_mm",
    )

    @property
    def on(self) -> bool:
        """Whether a trigger is set."""
        return remesh_on(vars(self))


TRIGGERS = ("quality_below", "every_steps", "every_stroke_mm", "corner_depth_ratio",
            "fold_angle_deg")  # fmt: skip


TRIGGERS_OFF = " = 0, ".join(f"remesh.{k}" for k in TRIGGERS) + " = 0"


def remesh_on(section: dict) -> bool:
    """Whether a [remesh] section (a dict of its keys) sets a trigger."""
    return any(section[k] > 0 for k in TRIGGERS)


@section("material")
@dataclass(frozen=True, kw_only=True)
class MaterialConfig:
    """[material]: the constitutive law and its parameters."""

    preset: str = key(
        "al1100_673K", doc="material preset name (jaxform/materials/data) or a .toml path"
    )
    density_kg_m3: float | None = key(
        low=0.0,
        low_open=True,
        high=1e5,
        doc="density (kg/m^3) for thermal.model = coupled; default: the preset's [thermal] value",
    )
    specific_heat_J_kgK: float | None = key(
        low=0.0,
        low_open=True,
        high=1e5,
        doc="specific heat (J/kg K) for thermal.model = coupled; default: the preset's",
    )
    conductivity_W_mK: float | None = key(
        low=0.0,
        low_open=True,
        high=1e4,
        doc="thermal conductivity (W/m K) for thermal.model = coupled; default: the preset's",
    )


@section("die")
@dataclass(frozen=True, kw_only=True)
class DieConfig:
    """[die]: the rigid top die: profile, motion, stroke."""

    speed_mm_s: float | None = key(
        low=0.0,
        low_open=True,
        doc="ram speed (mm/s): the dies close at this speed (each moves at half of it towards the"
        " mid-plane; a block's die at all of it; full height: shared with the bottom die by "
        "bottom_die.speed_share); required unless a path table is given",
    )
    reduction: float | None = key(
        low=0.0,
        high=1.0,
        low_open=True,
        high_open=True,
        doc="final height reduction (fraction of the initial height; block: of its depth); the "
        "run ends when the ram stroke reaches it",
    )
    profile_mm: tuple[tuple[float, float], ...] = key(
        [],
        doc="top-die profile as [r_mm, z_mm] points at t = 0, walked with the workpiece on the "
        "right (from the axis outward for a top die); [] = flat die on the billet's top face",
    )
    profile_kind: str = _profile_kind_key()
    path_time_s: tuple[float, ...] = key(
        [], doc="die path table: times (s), starting at 0 ([] = constant speed)"
    )
    path_travel_mm: tuple[float, ...] = key(
        [],
        doc="die path table: downward travel of the top die relative to the mid-plane at those "
        "times (mm), starting at 0 (half height: the ram stroke is twice it; full height: it "
        "plus the bottom die's rise)",
    )
    corner_radius_mm: float = _corner_radius_key(
        "radius of the arcs that round the profile's vertices (mm): the die surface is C1; "
        "where two segments are too short for it, the arc runs between their midpoints (so "
        "sampled fillets and splines keep their shape)"
    )
    corner_contact: bool = key(
        False,
        doc="also hold the workpiece's free-surface facets off the die's convex arcs (one "
        "normal multiplier per facet, frictionless; only where the profile turns convex): "
        "without it a convex die corner reaches between two contact nodes into the "
        "material (history die_overlap_mm). Straight facets cannot wrap a corner, so on a "
        "coarse mesh it stiffens the response (docs: scenes)",
    )
    closed: bool = key(
        False,
        doc="the profile closes a cavity with the mid-plane: report die_fill (cavity volume "
        "filled with material / cavity volume) in the history",
    )
    part_radius_mm: float = key(
        0.0,
        low=0.0,
        doc="closed dies with a flash land: the radius (mm) where the part's cavity ends; "
        "die_fill then counts the cavity at r <= part_radius_mm only, and the history "
        "gains flash_volume_mm3, the material beyond it (whole workpiece: both halves of "
        "a half-height model; per mm of depth in plane strain). 0: the whole cavity is "
        "the part",
    )


@section("press")
@dataclass(frozen=True, kw_only=True)
class PressConfig:
    """[press]: the machine that drives the top die (docs: presses)."""

    model: str = key(
        "speed",
        choices=("speed", "crank", "screw", "hammer"),
        doc="'speed': the die moves at die.speed_mm_s or along the die path table (the "
        "default; a hydraulic press); 'crank': a mechanical crank press (slider-crank "
        "motion to bottom dead centre); 'screw': a screw press, one stroke that ends when "
        "the flywheel energy is spent; 'hammer': press.blows blows of press.energy_J each",
    )
    capacity_N: float = key(
        0.0,
        low=0.0,
        doc="press capacity (N): the run stops where the ram force reaches it, with the "
        "history up to there written (0 = no limit)",
    )
    stroke_mm: float = key(
        100.0, low=0.0, low_open=True, doc="crank: the press stroke (mm), twice the crank radius"
    )
    strokes_per_min: float = key(
        30.0, low=0.0, high=6000.0, low_open=True, doc="crank: strokes per minute (1/min)"
    )
    rod_length_mm: float = key(
        400.0,
        low=0.0,
        low_open=True,
        doc="crank: connecting-rod length (mm), more than half the stroke; the crank starts at "
        "the angle from which the ram travels die.reduction x the height to bottom dead centre",
    )
    energy_J: float = key(
        1.0,
        low=0.0,
        high=1e9,
        low_open=True,
        doc="screw: flywheel energy; hammer: blow energy (J = 1000 N mm), the ram's kinetic "
        "energy at impact",
    )
    efficiency: float = key(
        0.8,
        low=0.0,
        high=1.0,
        low_open=True,
        doc="screw, hammer: share of the energy done as work on the part (the rest is lost "
        "in the frame, the anvil and the foundation)",
    )
    impact_speed_mm_s: float = key(
        5000.0,
        low=0.0,
        low_open=True,
        doc="screw, hammer: ram speed at the start of a blow (mm/s); it falls with the work "
        "done, v = v0 sqrt(1 - W / (efficiency x energy))",
    )
    blows: int = key(1, low=1, high=1000, doc="hammer: number of blows (a screw press: 1)")
    steps_per_blow: int = key(
        10,
        low=2,
        high=10000,
        doc="screw, hammer: load steps of each blow (each does an equal share of the work "
        "left); the step size of an energy-limited run",
    )


@section("bottom_die")
@dataclass(frozen=True, kw_only=True)
class BottomDieConfig:
    """[bottom_die]: the rigid die under a full-height workpiece (billet.full_height or
    ring.full_height = true): profile, motion; friction as [friction]."""

    profile_mm: tuple[tuple[float, float], ...] = key(
        [],
        doc="bottom-die profile as [r_mm, z_mm] points at t = 0, from the axis outward (the "
        "workpiece above it); [] = flat die on the bottom face z = -H/2",
    )
    profile_kind: str = _profile_kind_key()
    mirror: bool = key(
        False,
        doc="the bottom die is the top die's profile mirrored about z = 0 (profile_mm must be "
        "[]): with speed_share = 0.5 the full-height twin of the half-height model",
    )
    speed_share: float = key(
        0.0,
        low=0.0,
        high=1.0,
        high_open=True,
        doc="share of the ram speed die.speed_mm_s that the bottom die rises at (the top die "
        "descends at the rest): 0 = a fixed anvil, 0.5 = both dies move towards z = 0",
    )
    path_time_s: tuple[float, ...] = key(
        [], doc="bottom-die path table (with die.path_time_s): times (s), starting at 0"
    )
    path_travel_mm: tuple[float, ...] = key(
        [],
        doc="bottom-die path table: upward travel at those times (mm), starting at 0 ([] with "
        "a top-die path table: the bottom die stays fixed); the ram stroke is the top die's "
        "travel plus this",
    )
    corner_radius_mm: float = _corner_radius_key(
        "radius of the arcs that round the profile's vertices (mm), as die.corner_radius_mm"
    )


@section("side_die")
@dataclass(frozen=True, kw_only=True)
class SideDieConfig:
    """[side_die]: a third rigid die, a mandrel in a ring's bore or a container wall beside
    the workpiece, with its own profile and vertical path; friction as [friction]."""

    profile_mm: tuple[tuple[float, float], ...] = key(
        [],
        doc="side-die profile as [r_mm, z_mm] points at t = 0, walked with the workpiece on "
        "the right (a mandrel in the bore: upwards; a wall outside: downwards); [] = none",
    )
    path_time_s: tuple[float, ...] = key(
        [], doc="side-die path table: times (s), starting at 0 ([] = fixed)"
    )
    path_travel_mm: tuple[float, ...] = key(
        [], doc="side-die path table: downward travel at those times (mm), starting at 0"
    )
    corner_radius_mm: float = _corner_radius_key(
        "radius of the arcs that round the profile's vertices (mm), as die.corner_radius_mm"
    )


FRICTION_MODELS = ("none", "coulomb", "shear", "sticking")
# the coefficient key of each friction model that has one
FRICTION_COEFFICIENT = {"coulomb": "mu", "shear": "m"}


@section("friction")
@dataclass(frozen=True, kw_only=True)
class FrictionConfig:
    """[friction]: the friction law at the dies (each die's own [<die>.friction] table
    may replace any of its keys)."""

    model: str = key("none", choices=FRICTION_MODELS, doc="die-workpiece friction law")
    mu: float = key(0.0, low=0.0, high=10.0, doc="Coulomb coefficient (friction.model = coulomb)")
    m: float = key(
        0.0,
        low=0.0,
        high=1.0,
        doc="shear friction factor, tau = m sigma_eq/sqrt(3) (friction.model = shear)",
    )


# the die sections that may hold their own friction law, a [<die>.friction] sub-table
FRICTION_DIES = ("die", "bottom_die", "side_die")


@dataclass(frozen=True, kw_only=True)
class DieFrictionConfig:
    """[die.friction], [bottom_die.friction], [side_die.friction]: that die's own friction
    law; a key left out takes [friction]'s (:func:`die_friction`)."""

    model: str | None = key(
        choices=FRICTION_MODELS, doc="this die's friction law (default: friction.model)"
    )
    mu: float | None = key(
        low=0.0, high=10.0, doc="this die's Coulomb coefficient (default: friction.mu)"
    )
    m: float | None = key(low=0.0, high=1.0, doc="this die's shear factor (default: friction.m)")


for _die in FRICTION_DIES:
    section(f"{_die}.friction")(DieFrictionConfig)
# keys with no default that take [friction]'s value where left out
_INHERITED = {(f"{d}.friction", k) for d in FRICTION_DIES for k in ("model", "mu", "m")}


@section("wear")
@dataclass(frozen=True, kw_only=True)
class WearConfig:
    """[wear]: die wear by Archard's law, dw/dt = k p |v_slip|^b / H^c (docs: outputs)."""

    on: bool = key(False, doc="integrate the wear depth along every die surface (wear.csv)")
    k: float = key(
        1e-4,
        low=0.0,
        high=1.0,
        low_open=True,
        doc="wear coefficient K (-, for b = c = 1: wear depth per mm slid per unit p / H; "
        "else mm^(1-b) s^(b-1) MPa^(c-1))",
    )
    hardness_MPa: float = key(
        6000.0, low=1.0, high=1e5, doc="die hardness H (MPa), every die unless by_die is given"
    )
    hardness_by_die_MPa: tuple[float, ...] = key(
        [],
        doc="hardness H of each die (MPa, > 0), in the order top, bottom, side ([] = "
        "wear.hardness_MPa for all)",
    )
    hardness_slope_MPa_K: float = key(
        0.0,
        low=-100.0,
        high=100.0,
        doc="change of every die's hardness with its temperature (MPa/K): H(T) = H + slope "
        "(T - wear.hardness_reference_K), at least 1 MPa; T is thermal.die_temperature_K "
        "(with its table in coupled runs)",
    )
    hardness_reference_K: float = key(
        293.0, low=1.0, high=5000.0, doc="temperature at which the hardness is given (K)"
    )
    b: float = key(1.0, low=0.1, high=4.0, doc="exponent of the slip speed |v_slip| (-)")
    c: float = key(1.0, low=0.0, high=4.0, doc="exponent of the hardness H (-)")
    stations: int = key(
        101, low=2, high=2001, doc="stations along each die surface, equally spaced in arc length"
    )


@section("thermal")
@dataclass(frozen=True, kw_only=True)
class ThermalConfig:
    """[thermal]: heat conduction in the workpiece, coupled with the mechanics."""

    model: str = key(
        "none",
        choices=("none", "coupled"),
        doc="none: isothermal (the material at its preset temperature); coupled: a nodal "
        "temperature solved in the same Newton as the mechanics",
    )
    billet_temperature_K: float = key(
        673.0, low=1.0, high=5000.0, doc="initial workpiece temperature (K)"
    )
    die_temperature_K: float = key(673.0, low=1.0, high=5000.0, doc="die temperature (K)")
    air_temperature_K: float = key(293.15, low=1.0, high=5000.0, doc="ambient temperature (K)")
    htc_die_W_m2K: float = key(
        10000.0, low=0.0, high=1e7, doc="contact heat transfer coefficient to the dies (W/m^2 K)"
    )
    htc_air_W_m2K: float = key(
        20.0, low=0.0, high=1e7, doc="convection coefficient to the air (W/m^2 K)"
    )
    emissivity: float = key(0.1, low=0.0, high=1.0, doc="emissivity of the free surface")
    taylor_quinney: float = key(
        0.9, low=0.0, high=1.0, doc="fraction of the plastic work turned into heat"
    )
    die_path_time_s: tuple[float, ...] = key(
        [],
        doc="times (s) of a die temperature path, from 0, increasing ([] = constant die "
        "temperature)",
    )
    die_path_change_K: tuple[float, ...] = key(
        [],
        doc="the die temperature's change (K) from thermal.die_temperature_K at those times "
        "(linear between them, held after the last)",
    )
    dwell_s: float = key(
        0.0,
        low=0.0,
        high=1e5,
        doc="a first stage (s): the billet waits in air (the transfer to the press) before the "
        "dies move; no heat flows to the dies during it (time.dt_s still bounds its steps)",
    )


@section("time")
@dataclass(frozen=True, kw_only=True)
class TimeConfig:
    """[time]: the load steps."""

    dt_s: float = key(low=0.0, low_open=True, doc="largest time step (s): steps adapt below it")
    dt_growth: float = key(
        1.5,
        low=1.0,
        high=4.0,
        doc="after an easy step (no cutback, few Newton iterations) the next step grows by this "
        "factor, up to time.dt_s (1: never grows back)",
    )
    alpha: float = key(
        0.5, low=0.0, high=1.0, doc="generalized mid-point parameter of the strain increment"
    )


@section("solver")
@dataclass(frozen=True, kw_only=True)
class SolverConfig:
    """[solver]: Newton, linear solver, chunks, memory, compilation cache."""

    max_newton_iterations: int = key(
        25,
        low=1,
        high=1000,
        doc="Newton iterations per step before a cutback (modified Newton: those with a new "
        "Jacobian; up to 3x as many more with a kept factorization)",
    )
    rtol: float = key(
        1e-10,
        low=0.0,
        high=1.0,
        low_open=True,
        high_open=True,
        doc="relative residual tolerance of Newton",
    )
    max_cutbacks: int = key(6, low=0, high=30, doc="times a failed step may be halved")
    line_search: bool = key(True, doc="backtracking line search in Newton")
    linear: str = key(
        "auto",
        choices=("auto", "dense", "sparse", "jax-sparse"),
        doc="linear solver backend (auto: on CPU dense LU below 100 unknowns, klujax sparse LU "
        "above; on a GPU dense LU below 20 000, jax-sparse (cuSolver) above; see "
        "jaxform/linear.py)",
    )
    newton: str = key(
        "auto",
        choices=("auto", "newton", "modified"),
        doc="newton: a new Jacobian and factorization every iteration; modified: one "
        "factorization kept across iterations and steps, refreshed when a step contracts the "
        "residual by less than 2x (needs linear = dense or sparse); auto: modified on the "
        "sparse backend from MODIFIED_MIN_UNKNOWNS unknowns, newton below (see "
        "jaxform/solver.py)",
    )
    anderson_depth: int = key(
        3,
        low=0,
        high=10,
        doc="modified Newton: each step with a kept factorization is mixed with up to this many "
        "earlier ones (Anderson acceleration; fewer iterations for the same root; 0: plain "
        "steps; see jaxform/solver.py)",
    )
    adjoint_memory_mb: float = key(
        4096.0,
        low=0.0,
        doc="memory (MB) a gradient run may hold in forward factorizations kept for its reverse "
        "pass, which then refines each step's adjoint solve with the kept factors instead of "
        "factoring again; the last steps that fit are kept, the others factor in the reverse "
        "pass (0: none kept; ~69 MB a step at 100 x 100 with klujax; see "
        "jaxform/gradients.py)",
    )
    chunk_steps: int = key(
        8,
        low=1,
        high=10000,
        doc="load steps per compiled chunk (progress is reported between chunks)",
    )
    compilation_cache_dir: str = key(
        "auto",
        doc="where compiled programs are kept for the next run: a directory, 'off', or 'auto' "
        "(the environment variable JAXFORM_CACHE_DIR, else ~/.cache/jaxform; see "
        "jaxform/cache.py)",
    )


@section("output")
@dataclass(frozen=True, kw_only=True)
class OutputConfig:
    """[output]: what a run writes."""

    fields: bool = key(True, doc="write ParaView fields (VTU series)")
    plots: bool = key(True, doc="write PNG plots")
    profile_strokes_mm: tuple[float, ...] = key(
        [],
        doc="ram strokes (mm) at which the contact pressure/slip profile is plotted ([] = "
        "25/50/75/100 %)",
    )
    animation: bool = key(
        False,
        doc="write animation.gif: the section through the run (deformed mesh, equivalent "
        "plastic strain, the dies) from the stored fields; needs output.plots",
    )
    animation_frames: int = key(
        40,
        low=2,
        high=1000,
        doc="the animation's frames at most (history rows evenly spread, first and last kept)",
    )
    lap_angle_deg: float = key(
        10.0,
        low=0.0,
        high=90.0,
        doc="report a lap (fold) where the narrowest air wedge of the free surface (history "
        "fold_angle_deg: against itself or against a die) closes below this (deg; 0 = never)",
    )
    damage_critical: float = key(
        0.0,
        low=0.0,
        high=100.0,
        doc="critical value of output.damage_criterion: elements at or above it are flagged "
        "(cell field damage_flag, damage.png; history damage_flagged) (0 = no flag)",
    )
    damage_criterion: str = key(
        "cl",
        choices=("cl", "brozzo", "ayada"),
        doc="the damage integral output.damage_critical applies to: normalized "
        "Cockcroft-Latham, Brozzo or Ayada (docs: outputs)",
    )
    flow_line_spacing_mm: float = key(
        0.0,
        low=0.0,
        high=1e4,
        doc="follow material lines of the initial section at this spacing (mm) through the "
        "run and its remeshes: flow_lines.png, fields/flow_lines_*.vtu (0 = none)",
    )


@section("design")
@dataclass(frozen=True, kw_only=True)
class DesignConfig:
    """[design]: design problems (jaxform design and taylor-test)."""

    objective: str = key(
        "forging_work",
        choices=(
            "forging_work",
            "peak_force",
            "side_straightness",
            "shape_target",
            "force_misfit",
            "eqps_spread",
            "die_fill",
            "temperature_misfit",
            "max_damage",
            "wear_depth",
        ),
        doc="design objective (jaxform design / taylor-test), a function of the run: force "
        "integral over stroke (N mm), peak ram force (N), mean squared deviation of the final"
        " side from straight (mm^2), of chosen nodes from target positions (mm^2), "
        "force-stroke misfit against a target curve, variance of eqps, 1 - die fill, mean "
        "squared misfit of the mean temperature history against a target (K^2), a smooth "
        "maximum of output.damage_criterion's damage at the end (-) or of the die wear "
        "depth (mm; needs wear.on) (design.smooth_max_p)",
    )
    smooth_max_p: float = key(
        8.0,
        low=1.0,
        high=64.0,
        doc="exponent p of the power mean (mean of x^p)^(1/p) that objectives max_damage "
        "and wear_depth take as a smooth maximum: between N^(-1/p) max and max",
    )
    max_temperature_K: float = key(
        0.0,
        low=0.0,
        high=5000.0,
        doc="a limit on the hottest node (K; coupled runs): the objective gains "
        "design.temperature_penalty x sum over steps of max(0, T_max - limit)^2 (0: none)",
    )
    temperature_penalty: float = key(
        1.0,
        low=0.0,
        low_open=True,
        doc="weight of the temperature-limit penalty (objective units per K^2)",
    )
    variables: tuple[str, ...] = key(
        ["material"],
        choices=("material", "friction", "speed", "preform", "nodes", "die", "thermal"),
        doc="design variable groups jaxform design optimizes",
    )
    material_params: tuple[str, ...] = key(
        [],
        doc="material parameters of the 'material' group (names of the law's parameters); "
        "empty: the law's own choice (anand: s0_MPa, h0_MPa, s_hat_MPa; j2: sigma_y0_MPa, "
        "H_MPa; elastic: G_MPa, K_MPa)",
    )
    material_start_factor: float = key(
        1.0,
        low=0.0,
        low_open=True,
        doc="the design starts from the material parameters times this (e.g. 0.7 to identify from"
        " 30 % off)",
    )
    thermal_params: tuple[str, ...] = key(
        [],
        doc="inputs of the 'thermal' group: any of billet_temperature_K, die_temperature_K, "
        "htc_die_W_m2K, taylor_quinney (thermal.* keys); empty: all four",
    )
    preform_modes: int = key(3, low=1, high=20, doc="cosine modes of the preform profile")
    preform_amplitude_max: float = key(
        0.2,
        low=0.0,
        high=0.9,
        low_open=True,
        doc="bound on each preform mode amplitude (fraction of the radius)",
    )
    node_offset_max_mm: float = key(
        0.1,
        low=0.0,
        low_open=True,
        doc="bound on each initial node coordinate's offset of the 'nodes' group (mm)",
    )
    die_points: tuple[float, ...] = key(
        [], doc="indices of die.profile_mm points whose z is a design variable ([] = all)"
    )
    die_offset_max_mm: float = key(
        1.0, low=0.0, low_open=True, doc="bound on each die point's vertical offset (mm)"
    )
    bound_factor: float = key(
        2.0,
        low=1.0,
        high=1000.0,
        low_open=True,
        doc="material parameters and ram speed stay within [p0 / factor, p0 * factor]",
    )
    target_csv: str = key(
        "",
        doc="target for temperature_misfit (CSV with time_s, mean_temperature_K), "
        "force_misfit (CSV with stroke_mm, force_N) or shape_target (CSV with "
        "node, r_mm, z_mm)",
    )
    optimizer: str = key(
        "lbfgs",
        choices=("lbfgs", "adam"),
        doc="optax optimizer (L-BFGS with zoom line search, or Adam)",
    )
    iterations: int = key(20, low=1, high=10000, doc="optimizer iterations")
    learning_rate: float = key(
        0.05, low=0.0, low_open=True, doc="Adam step size in the scaled design variables"
    )


STUDY_PLANS = ("latin_hypercube", "sobol", "monte_carlo", "factorial")


@section("study")
@dataclass(frozen=True, kw_only=True)
class StudyConfig:
    """[study]: a design of experiments or a Monte-Carlo study (jaxform study): inputs,
    plan, responses (docs/doe.md)."""

    inputs: tuple[str, ...] = key(
        [],
        doc="the inputs: 'section.key = uniform(low, high)', 'normal(mean, std)', "
        "'lognormal(mu, sigma)' (of the key's log), or 'levels(a, b, ...)', any numeric key "
        "(values in its unit; each sample is the scene with these --set overrides)",
    )
    plan: str = key(
        "latin_hypercube",
        choices=STUDY_PLANS,
        doc="the samples: Latin hypercube, scrambled Sobol sequence, plain Monte Carlo "
        "(study.samples of each, from study.seed) or the full factorial of the levels",
    )
    samples: int = key(16, low=1, high=100_000, doc="samples of a random or Sobol plan")
    levels: int = key(
        3,
        low=2,
        high=100,
        doc="factorial plan: levels of an input given by a distribution (uniform: equally "
        "spaced from low to high; normal, lognormal: the quantiles (i + 1/2)/levels)",
    )
    seed: int = key(0, low=0, high=2**31 - 1, doc="seed of the random and Sobol plans")
    responses: tuple[str, ...] = key(
        ["force_N:max"],
        doc="what each sample reports: 'column:end', 'column:max' or 'column:min' of any "
        "history column (e.g. force_N:max, mean_temperature_K:end), 'fill' (die_fill at "
        "the end), 'flash' (flash_volume_mm3 at the end), 'laps' (number of laps found)",
    )
    gradients: bool = key(
        False,
        doc="also the exact gradient of each response in each input at each sample "
        "(inputs of the friction, speed and thermal design groups; no remeshing)",
    )
    retries: int = key(
        3,
        low=0,
        high=100,
        doc="times a sample whose worker died (killed, out of memory) runs again elsewhere",
    )
    batch: int = key(
        0,
        low=0,
        high=4096,
        doc="0: each sample is a run of its own (jaxform run: adaptive steps); B > 0: B "
        "samples per task as one vmapped program (jaxform.batch) over the base scene's fixed "
        "step schedule (inputs and responses as for study.gradients; same mesh)",
    )


def _schema_of(cls: type) -> dict[str, Field]:
    return {f.name: Field(_KINDS[f.type], **f.metadata["key"]) for f in dataclasses.fields(cls)}


SCHEMA: dict[str, dict[str, Field]] = {name: _schema_of(cls) for name, cls in SECTIONS.items()}


def _bound_lengths(schema: dict[str, dict[str, Field]]) -> dict[str, dict[str, Field]]:
    """The schema with every unbounded length or speed key capped at MAX_LENGTH_MM."""

    def capped(key: str, f: Field) -> Field:
        is_length = key.endswith("_mm") or key.endswith("_mm_s")
        if f.kind == "float" and is_length and f.low is not None and f.high is None:
            return replace(f, high=MAX_LENGTH_MM, high_inclusive=True)
        return f

    return {s: {k: capped(k, f) for k, f in t.items()} for s, t in schema.items()}


SCHEMA = _bound_lengths(SCHEMA)


@dataclass(frozen=True, kw_only=True)
class Config:
    """A validated scene config, typed and frozen: one attribute per section, None where
    the scene has no such section (a membrane has no die; a billet no load).  Built by
    :func:`typed` from :func:`load_config`'s document; :meth:`to_dict` gives it back."""

    billet: BilletConfig | None = None
    ring: RingConfig | None = None
    block: BlockConfig | None = None
    membrane: MembraneConfig | None = None
    load: LoadConfig | None = None
    mesh: MeshConfig
    remesh: RemeshConfig
    material: MaterialConfig
    die: DieConfig | None = None
    press: PressConfig | None = None
    bottom_die: BottomDieConfig | None = None
    side_die: SideDieConfig | None = None
    friction: FrictionConfig | None = None
    # the dies' own friction tables ([die.friction] etc.; None outside a die scene)
    die_friction: DieFrictionConfig | None = None
    bottom_die_friction: DieFrictionConfig | None = None
    side_die_friction: DieFrictionConfig | None = None
    wear: WearConfig | None = None
    thermal: ThermalConfig
    time: TimeConfig
    solver: SolverConfig
    output: OutputConfig
    design: DesignConfig
    study: StudyConfig

    @property
    def workpiece(self) -> str:
        """The workpiece section's name: 'billet', 'ring', 'block' or 'membrane'."""
        return next(w for w in WORKPIECES if getattr(self, w) is not None)

    def to_dict(self) -> dict:
        """The TOML document (sections present, lists for tuples)."""
        return {
            name: {f.name: _thaw(getattr(sec, f.name)) for f in dataclasses.fields(sec)}
            for name in SECTIONS
            if (sec := getattr(self, _attribute(name))) is not None
        }

    def friction_key(self, die: str, coefficient: str) -> str:
        """The config key that sets ``coefficient`` (mu or m) of die section ``die``."""
        return friction_source(self.to_dict(), die, coefficient)

    def friction_of(self, die: str) -> FrictionConfig:
        """The friction law of die section ``die`` (of FRICTION_DIES): its own table's
        keys over [friction]'s (:func:`die_friction`)."""
        return FrictionConfig(**die_friction(self.to_dict(), die))


def _attribute(section_name: str) -> str:
    """The :class:`Config` attribute of a section ('die.friction' -> 'die_friction')."""
    return section_name.replace(".", "_")


def die_friction(cfg: dict, die: str) -> dict:
    """The friction keys (model, mu, m) of die section ``die`` in a validated document:
    each from its [<die>.friction] table where given there, else from [friction]."""
    own = cfg.get(f"{die}.friction") or {}
    return {k: v if own.get(k) is None else own[k] for k, v in cfg["friction"].items()}


def friction_source(cfg: dict, die: str, coefficient: str) -> str:
    """The config key that sets ``coefficient`` (mu or m) of die section ``die``."""
    own = cfg.get(f"{die}.friction") or {}
    return f"{die}.friction.{coefficient}" if own.get(coefficient) is not None else (
        f"friction.{coefficient}")  # fmt: skip


def friction_keys(cfg: dict) -> set[str]:
    """The config keys that set a coefficient of some die's friction law in a validated
    die scene (e.g. {'friction.m'}, {'friction.mu', 'side_die.friction.m'})."""
    out = set()
    for die in friction_dies(cfg):
        coefficient = FRICTION_COEFFICIENT.get(die_friction(cfg, die)["model"])
        if coefficient:
            out.add(friction_source(cfg, die, coefficient))
    return out


def friction_dies(cfg: dict) -> tuple[str, ...]:
    """The die sections of a validated die scene that build a die: the top die, the
    bottom die of a full-height workpiece, a side die with a profile."""
    piece = next((cfg[w] for w in ("billet", "ring") if w in cfg), {})
    full = piece.get("full_height", False)
    side = bool(cfg.get("side_die", {}).get("profile_mm"))
    return ("die",) + (("bottom_die",) if full else ()) + (("side_die",) if side else ())


def _freeze(value: Any) -> Any:
    return tuple(_freeze(v) for v in value) if isinstance(value, list) else value


def _thaw(value: Any) -> Any:
    return [_thaw(v) for v in value] if isinstance(value, tuple) else value


def typed(cfg: dict) -> Config:
    """The :class:`Config` of a document from :func:`load_config` (validated already)."""
    return Config(
        **{
            _attribute(name): SECTIONS[name](**{k: _freeze(v) for k, v in table.items()})
            for name, table in cfg.items()
        }
    )


# Exactly one workpiece section: a solid billet, a ring, an indented block (all pressed by
# a die) or a membrane (clamped, loaded by a traction; no die).
WORKPIECES = ("billet", "ring", "block", "membrane")
# sections that only some workpieces use
_DIE_SECTIONS = ("die", "press", "friction", "wear")
_FORGING_SECTIONS = ("bottom_die", "side_die")  # billets and rings only
_LOAD_SECTIONS = ("load",)


def _workpiece(raw: dict) -> str:
    given = [w for w in WORKPIECES if w in raw]
    if len(given) != 1:
        raise ConfigError(
            f"give exactly one workpiece section, "
            f"{', '.join(f'[{w}]' for w in WORKPIECES)} "
            f"(found {', '.join(given) or 'none'})"
        )
    return given[0]


def _applies(section: str, kind: str) -> bool:
    """Whether a section belongs in a scene with workpiece ``kind``."""
    section = section.split(".")[0]  # a die's friction table goes with its die
    if section in WORKPIECES:
        return section == kind
    if section in _DIE_SECTIONS:
        return kind != "membrane"
    if section in _FORGING_SECTIONS:
        return kind in ("billet", "ring")
    if section in _LOAD_SECTIONS:
        return kind == "membrane"
    return True


def _parse_override(text: str) -> tuple[str, str, Any]:
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
        raise ConfigError(
            f"{name} = {value!r}: must be a{'n' if f.kind == 'int' else ''} "
            f"{f.kind} in {f.allowed()}"
        )
    if f.kind == "int" and not isinstance(value, int):
        raise ConfigError(f"{name} = {value!r}: must be an int in {f.allowed()}")
    value = int(value) if f.kind == "int" else float(value)
    if not math.isfinite(value):
        raise ConfigError(f"{name} = {value!r}: must be a finite number in {f.allowed()}")
    ok = True
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
        _check_lengths(name, value)
        return [float(v) for v in value]
    if f.kind == "strs":
        if not all(isinstance(v, str) for v in value):
            raise ConfigError(f"{name} = {value!r}: must be a list of strings")
        bad = [v for v in value if f.choices is not None and v not in f.choices]
        if bad:
            raise ConfigError(
                f"{name} = {value!r}: {bad[0]!r} is not allowed; each entry must be {f.allowed()}"
            )
        return list(value)
    if not all(isinstance(p, list) and len(p) == 2 and all(_is_num(v) for v in p) for p in value):
        raise ConfigError(
            f"{name} = {value!r}: must be a list of [r_mm, z_mm] pairs of finite numbers"
        )
    _check_lengths(name, [v for p in value for v in p])
    return [[float(a), float(b)] for a, b in value]


def _check_lengths(name: str, values: list) -> None:
    """Entries of a list of lengths (key ending in _mm) lie within +-MAX_LENGTH_MM."""
    big = [v for v in values if abs(v) > MAX_LENGTH_MM]
    if name.endswith("_mm") and big:
        raise ConfigError(
            f"{name}: entry {big[0]!r} mm: every entry must lie in "
            f"[-{_num(MAX_LENGTH_MM)}, {_num(MAX_LENGTH_MM)}] mm"
        )


def _thermal_properties(out: dict) -> None:
    """Fill material.density_kg_m3, specific_heat_J_kgK and conductivity_W_mK from the
    preset's [thermal] table where not given; a coupled run needs all three."""
    mat = out["material"]
    keys = ("density_kg_m3", "specific_heat_J_kgK", "conductivity_W_mK")
    if any(mat[k] is None for k in keys):
        preset = load_thermal_properties(mat["preset"])
        for k in keys:
            if mat[k] is None:
                mat[k] = preset.get(k)
    missing = [k for k in keys if mat[k] is None]
    if out["thermal"]["model"] == "coupled" and missing:
        raise ConfigError(
            f"thermal.model = 'coupled' needs material.{missing[0]}: the preset "
            f"{mat['preset']!r} has no [thermal] table; give "
            + ", ".join(f"material.{k}" for k in missing)
        )


def _cross_checks(raw: dict, out: dict) -> None:
    """Rules that involve several keys."""
    _thermal_properties(out)
    th = out["thermal"]
    if th["dwell_s"] > 0.0 and th["model"] != "coupled":
        raise ConfigError("thermal.dwell_s > 0 needs thermal.model = 'coupled'")
    times, change = th["die_path_time_s"], th["die_path_change_K"]
    if len(times) != len(change):
        raise ConfigError(
            "thermal.die_path_time_s and thermal.die_path_change_K must have the same length"
        )
    if times and (times[0] != 0.0 or any(b <= a for a, b in zip(times, times[1:]))):
        raise ConfigError("thermal.die_path_time_s: must start at 0 s and increase")
    wear = out.get("wear")
    if wear and any(not v > 0.0 or v > 1e5 for v in wear["hardness_by_die_MPa"]):
        raise ConfigError("wear.hardness_by_die_MPa: every entry must lie in (0, 100000] MPa")
    rm = out["remesh"]
    if remesh_on(rm):
        if out["mesh"]["rezone_quality"] > 0.0:
            raise ConfigError(
                "mesh.rezone_quality > 0 and [remesh] both set: choose one (remeshing "
                "replaces the mesh, rezoning moves its nodes); set mesh.rezone_quality = 0"
            )
        if "membrane" in out:
            raise ConfigError(
                "[remesh]: a [membrane] scene cannot be remeshed (its load is given per "
                f"initial edge); set {TRIGGERS_OFF}"
            )
    if "membrane" in out:
        _membrane_checks(out)
        return
    if "block" in out:
        b = out["block"]
        for fine, full in (("fine_width_mm", "width_mm"), ("fine_depth_mm", "depth_mm")):
            if b[fine] > b[full]:
                raise ConfigError(
                    f"block.{fine} = {b[fine]!r}: must be <= block.{full} = {b[full]!r}"
                )
    energy = out["press"]["model"] in ("screw", "hammer")
    if out["die"]["reduction"] is None and not energy:
        f = SCHEMA["die"]["reduction"]
        raise ConfigError(f"missing required key die.reduction (float in {f.allowed()}): {f.doc}")
    if "ring" in out:
        r = out["ring"]
        if r["inner_diameter_mm"] >= r["outer_diameter_mm"]:
            raise ConfigError(
                f"ring.inner_diameter_mm = {r['inner_diameter_mm']!r}: must be "
                f"< ring.outer_diameter_mm = {r['outer_diameter_mm']!r}"
            )
    d = out["die"]
    _check_path("die", d, monotone=True)
    _press_checks(out)
    if not d["path_time_s"] and d["speed_mm_s"] is None and out["press"]["model"] == "speed":
        f = SCHEMA["die"]["speed_mm_s"]
        raise ConfigError(f"missing required key die.speed_mm_s (float in {f.allowed()}): {f.doc}")
    if d["profile_mm"] and len(d["profile_mm"]) < 2:
        raise ConfigError(
            "die.profile_mm: needs at least 2 [r_mm, z_mm] points (or [] for a flat die)"
        )
    if d["part_radius_mm"] > 0.0 and not d["closed"]:
        raise ConfigError(
            f"die.part_radius_mm = {d['part_radius_mm']!r}: needs die.closed = true "
            f"(it splits a closed die's cavity into the part and the flash land)"
        )
    if out["mesh"]["rezone_quality"] > 0.0 and out["mesh"]["file"]:
        raise ConfigError(
            "mesh.rezone_quality > 0 needs the structured mesh (mesh.file = ''): "
            "rezoning relocates the nodes of the logical grid"
        )
    if out["mesh"]["file"] and not Path(out["mesh"]["file"]).is_file():
        raise ConfigError(f"mesh.file = {out['mesh']['file']!r}: no such file")
    if "billet" in out or "ring" in out:
        _die_set_checks(raw, out)
    _friction_checks(raw, out)


def _friction_checks(raw: dict, out: dict) -> None:
    """A law with a coefficient has it given (in the die's own table or in [friction]);
    a die's own table belongs to a die the scene has."""
    need = FRICTION_COEFFICIENT
    fr = out["friction"]
    if fr["model"] in need and need[fr["model"]] not in raw.get("friction", {}):
        k = need[fr["model"]]
        f = SCHEMA["friction"][k]
        raise ConfigError(f"friction.model = {fr['model']!r} needs friction.{k} ({f.kind} in "
                          f"{f.allowed()})")  # fmt: skip
    dies = friction_dies(out)
    for die in FRICTION_DIES:
        own = {k: v for k, v in raw.get(f"{die}.friction", {}).items() if v is not None}
        if own and die not in dies:
            raise ConfigError(
                f"{die}.friction.{sorted(own)[0]}: the scene has no {die} (a bottom die needs "
                "full_height = true, a side die side_die.profile_mm)"
            )
        model = die_friction(out, die)["model"]
        k = need.get(model)
        if own and k and k not in own and k not in raw.get("friction", {}):
            raise ConfigError(
                f"{die}.friction.model = {model!r} needs {die}.friction.{k} or friction.{k} "
                f"(float in {SCHEMA['friction'][k].allowed()})"
            )


def _press_checks(out: dict) -> None:
    """[press]: a machine other than 'speed' drives the top die alone (no path table, no
    shared bottom-die speed); a screw press makes one stroke; energy presses do not dwell."""
    pr, d = out["press"], out["die"]
    model = pr["model"]
    if model == "speed":
        return
    if d["path_time_s"]:
        raise ConfigError(
            f"press.model = {model!r} moves the die itself: set die.path_time_s = [] "
            "(path tables belong to press.model = 'speed')"
        )
    if "bottom_die" in out and out["bottom_die"]["speed_share"] > 0.0:
        raise ConfigError(
            f"bottom_die.speed_share > 0 needs press.model = 'speed' (a {model} press "
            "drives the top die; the bottom die stands)"
        )
    if model == "crank" and pr["rod_length_mm"] <= 0.5 * pr["stroke_mm"]:
        raise ConfigError(
            f"press.rod_length_mm = {pr['rod_length_mm']!r}: must be > press.stroke_mm / 2 = "
            f"{0.5 * pr['stroke_mm']!r} (the connecting rod must be longer than the crank)"
        )
    if model == "screw" and pr["blows"] != 1:
        raise ConfigError(f"press.blows = {pr['blows']!r}: a screw press makes one stroke (1)")
    if model in ("screw", "hammer") and (remesh_on(out["remesh"])
                                         or out["mesh"]["rezone_quality"] > 0.0):  # fmt: skip
        raise ConfigError(
            f"press.model = {model!r}: its blows run on one mesh; set mesh.rezone_quality "
            f"= 0 and leave [remesh] off ({TRIGGERS_OFF})"
        )
    if model in ("screw", "hammer") and out["thermal"]["dwell_s"] > 0.0:
        raise ConfigError(
            f"thermal.dwell_s > 0 needs press.model = 'speed' or 'crank' (a {model} "
            "starts at its blow)"
        )


def _check_path(section: str, d: dict, monotone: bool) -> None:
    """A path table ``section.path_time_s`` -> ``section.path_travel_mm``: same lengths,
    at least 2 rows from (0 s, 0 mm), times increasing (travel not decreasing if
    ``monotone``); an empty table passes."""
    t, s = d["path_time_s"], d["path_travel_mm"]
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


def _die_set_checks(raw: dict, out: dict) -> None:
    """The bottom and side dies of a billet or ring scene."""
    kind = "billet" if "billet" in out else "ring"
    full = out[kind]["full_height"]
    bd, sd, d = out["bottom_die"], out["side_die"], out["die"]
    given = {k for k, v in raw.get("bottom_die", {}).items()
             if v != SCHEMA["bottom_die"][k].default}  # fmt: skip
    if given and not full:
        raise ConfigError(
            f"bottom_die.{sorted(given)[0]}: a bottom die needs {kind}.full_height = true "
            "(a half-height model stands on its mid-plane, z = 0)"
        )
    if full:
        if bd["mirror"] and bd["profile_mm"]:
            raise ConfigError(
                "bottom_die.mirror = true takes the top die's profile: "
                "set bottom_die.profile_mm = []"
            )
        if bd["profile_mm"] and len(bd["profile_mm"]) < 2:
            raise ConfigError("bottom_die.profile_mm: needs at least 2 [r_mm, z_mm] points")
        _check_path("bottom_die", bd, monotone=True)
        if bd["path_time_s"] and not d["path_time_s"]:
            raise ConfigError(
                "bottom_die.path_time_s needs die.path_time_s (both dies on path tables); "
                "with die.speed_mm_s use bottom_die.speed_share"
            )
        if bd["speed_share"] > 0.0 and d["path_time_s"]:
            raise ConfigError(
                f"bottom_die.speed_share = {bd['speed_share']!r} shares die.speed_mm_s: with "
                "die.path_time_s give the bottom die's own bottom_die.path_time_s instead"
            )
        if out["mesh"]["rezone_quality"] > 0.0:
            raise ConfigError(
                f"mesh.rezone_quality > 0 needs a half-height model ({kind}.full_height = "
                "false): use [remesh] for a full-height one"
            )
    if sd["profile_mm"] and len(sd["profile_mm"]) < 2:
        raise ConfigError("side_die.profile_mm: needs at least 2 [r_mm, z_mm] points")
    _check_path("side_die", sd, monotone=False)
    if sd["path_time_s"] and not sd["profile_mm"]:
        raise ConfigError("side_die.path_time_s: needs side_die.profile_mm (no side die is set)")


def _membrane_checks(out: dict) -> None:
    m, ld = out["membrane"], out["load"]
    if out["mesh"]["geometry"] != "plane_strain":
        raise ConfigError(
            f"mesh.geometry = {out['mesh']['geometry']!r}: a [membrane] scene is "
            f"plane strain; set mesh.geometry = 'plane_strain'"
        )
    c = m["corners_mm"]
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
    if m["tip_mm"] and len(m["tip_mm"]) != 2:
        raise ConfigError(f"membrane.tip_mm = {m['tip_mm']!r}: must be [x_mm, y_mm] or []")
    if ld["edge"] == m["clamped_edge"]:
        raise ConfigError(f"load.edge = {ld['edge']!r}: must differ from membrane.clamped_edge")
    for key in ("force_x_N", "force_y_N"):
        if not math.isfinite(ld[key]):
            raise ConfigError(f"load.{key} = {ld[key]!r}: must be finite")
    if ld["force_x_N"] == 0.0 and ld["force_y_N"] == 0.0:
        raise ConfigError(
            "load.force_x_N and load.force_y_N are both 0: give the load's "
            "resultant (N per mm of depth)"
        )


def _size_checks(out: dict) -> None:
    """The mesh and the step count within MAX_ELEMENTS and MAX_STEPS; the design's start
    within its bounds."""
    m = out["mesh"]
    if m["nr"] * m["nz"] > MAX_ELEMENTS:
        raise ConfigError(
            f"mesh.nr x mesh.nz = {m['nr']} x {m['nz']} = {m['nr'] * m['nz']} "
            f"elements: at most {MAX_ELEMENTS} fit a run; use a coarser mesh"
        )
    t_end, what = _end_time(out)
    dt = out["time"]["dt_s"]
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
    d = out["design"]
    lo, hi = 1.0 / d["bound_factor"], d["bound_factor"]
    if not lo <= d["material_start_factor"] <= hi:
        raise ConfigError(
            f"design.material_start_factor = {d['material_start_factor']!r}: must "
            f"lie in [1/design.bound_factor, design.bound_factor] = "
            f"[{lo:.6g}, {hi:.6g}]"
        )


def _end_time(out: dict) -> tuple[float | None, str]:
    """(end time of the run in s, the keys that set it), or (None, '') where it is not
    known before the mesh is built (a mesh file sets the height) or the path table never
    reaches the stroke (refused when the scene is built)."""
    if "membrane" in out:
        return out["load"]["ramp_time_s"], "load.ramp_time_s"
    if out["mesh"]["file"]:
        return None, ""
    d = out["die"]
    kind = next(k for k in ("billet", "ring", "block") if k in out)
    key = f"{kind}.{'depth_mm' if kind == 'block' else 'height_mm'}"
    height = out[kind]["depth_mm" if kind == "block" else "height_mm"]
    if out["press"]["model"] != "speed":  # set by the press (jaxform.scenes)
        return None, ""
    if not d["path_time_s"]:
        return d["reduction"] * height / d["speed_mm_s"], f"die.reduction x {key} / die.speed_mm_s"
    full = kind == "block" or out[kind]["full_height"]
    target = d["reduction"] * height * (1.0 if full else 0.5)  # the dies' closure
    rows = list(zip(d["path_time_s"], d["path_travel_mm"]))
    bottom = out.get("bottom_die")
    if full and bottom is not None and bottom["path_time_s"]:  # the closure on both tables
        times = sorted(set(d["path_time_s"]) | set(bottom["path_time_s"]))
        closure = [float(_interp(t, d) + _interp(t, bottom)) for t in times]
        rows = list(zip(times, closure))
    for (t0, s0), (t1, s1) in zip(rows, rows[1:]):
        if s1 >= target:
            t = t0 + (target - s0) * (t1 - t0) / (s1 - s0) if s1 > s0 else t1
            return t, f"die.path_time_s to die.reduction x {key}"
    return None, ""


def _interp(t: float, d: dict) -> float:
    """A path table's travel at time t (mm; constant past its ends)."""
    rows = list(zip(d["path_time_s"], d["path_travel_mm"]))
    if t >= rows[-1][0]:
        return rows[-1][1]
    for (t0, s0), (t1, s1) in zip(rows, rows[1:]):
        if t0 <= t <= t1:
            return s0 + (t - t0) * (s1 - s0) / (t1 - t0)
    return rows[0][1]


# keys that may be left out even though they have no default (checked in _cross_checks)
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
    if isinstance(path_or_dict, dict):
        raw = copy.deepcopy(path_or_dict)
    else:
        raw = _read_toml(path_or_dict)
    # a multi-stage process is read by jaxform.process_config.load_document; here its
    # base sections are checked first, then it is refused (a command of one scene)
    process = raw.pop("process", None)
    _lift_friction_tables(raw)
    for text in overrides:
        section, key, value = _parse_override(text)
        sec = raw.setdefault(section, {})
        if not isinstance(sec, dict):
            raise ConfigError(f"{section}: must be a table of keys, not {sec!r}")
        sec[key] = value
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
    kind = _workpiece(raw)
    for section in raw:
        if not _applies(section, kind):
            raise ConfigError(
                f"[{section}] does not apply to a [{kind}] scene; allowed sections: "
                f"{', '.join(s for s in SCHEMA if _applies(s, kind))}"
            )
    out: dict[str, dict[str, Any]] = {}
    for section, fields in SCHEMA.items():
        if not _applies(section, kind):
            continue
        given = raw.get(section, {})
        out[section] = {}
        for key, f in fields.items():
            name = f"{section}.{key}"
            optional = (section, key) in _CONDITIONAL | _INHERITED
            if key in given and not (given[key] is None and optional):
                out[section][key] = _check(name, f, given[key])
            elif f.default is None and not optional:
                raise ConfigError(
                    f"missing required key {name} ({f.kind} in {f.allowed()}): {f.doc}"
                )
            else:
                out[section][key] = copy.deepcopy(f.default)
    _closed_die_remeshing(raw, out)
    _cross_checks(raw, out)
    _size_checks(out)
    if process is not None:
        raise ConfigError(
            "[[process.operation]]: a multi-stage process runs with `jaxform run` only "
            "(design and taylor-test take a config of one forming operation)"
        )
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
    raw = path_or_dict if isinstance(path_or_dict, dict) else _read_toml(path_or_dict)
    return set(raw) | {_parse_override(text)[0] for text in overrides}


def defaulted_sections(cfg: dict, given: set, command: str) -> list[str]:
    """One line for each section that a user would expect to write but that the
    validated config ``cfg`` took from the defaults (``given``: :func:`given_sections`):
    [material] always, [design] for ``jaxform design``."""
    lines = []
    if "material" in cfg and "material" not in given:
        lines.append(
            f"material: {cfg['material']['preset']} (default: the config has no [material] section)"
        )
    if command == "design" and "design" not in given:
        d = cfg["design"]
        lines.append(
            f"design: the config has no [design] section: the defaults, variables "
            f"{', '.join(d['variables'])}, objective {d['objective']}, {d['iterations']} "
            f"iterations of {d['optimizer']}"
        )
    return lines


def _read_toml(path: str | PathLike) -> dict:
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
    return _read_toml(path)


def dump_config(cfg: dict, path: str | PathLike) -> None:
    """Write a (resolved) config as TOML (keys whose value is unset are left out; a die's
    friction table as its sub-table [die.friction], where it sets a key)."""
    clean = {s: {k: v for k, v in t.items() if v is not None} for s, t in cfg.items()}
    for name in [s for s in clean if "." in s]:
        table = clean.pop(name)
        if table:
            die = name.split(".")[0]
            clean[die] = {**clean.get(die, {}), "friction": table}
    Path(path).write_bytes(tomli_w.dumps(clean).encode())


def describe_schema() -> str:
    """A Markdown table (key | type | default | allowed | meaning) of every key."""
    rows = ["| key | type | default | allowed | meaning |", "|---|---|---|---|---|"]
    for section, fields in SCHEMA.items():
        for key, f in fields.items():
            if (section, key) in _INHERITED:
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


GRADIENT_GROUPS = SCHEMA["design"]["variables"].choices
# design objectives that read the force-stroke history or the carried state (damage, wear):
# the ones a remeshed run has
REMESH_OBJECTIVES = ("forging_work", "peak_force", "force_misfit", "max_damage", "wear_depth")


def check_design_run(cfg: dict) -> None:
    """:func:`check_gradient_run` for ``jaxform design``: the groups of design.variables."""
    check_gradient_run(cfg, cfg["design"]["variables"], "design.variables")


def check_gradient_run(
    cfg: dict, groups: list[str] | None = None, where: str = "design.variables"
) -> None:
    """Refuse a validated config that a gradient run (jaxform design, taylor-test) cannot
    use, before anything is built: rezoning, design groups the scene lacks (``groups``:
    the groups asked for, ``where`` names the key or flag that asked; None = the scene's
    own), an objective whose inputs are missing."""
    q = cfg["mesh"]["rezone_quality"]
    if q > 0.0:
        raise ConfigError(
            f"mesh.rezone_quality = {q!r}: gradient runs need 0 (a rezoned "
            f"history has no gradient); --set mesh.rezone_quality=0"
        )
    rm = cfg["remesh"]
    d = cfg["design"]
    if remesh_on(rm):
        if d["objective"] not in REMESH_OBJECTIVES:
            raise ConfigError(
                f"design.objective = {d['objective']!r} reads the initial mesh's nodes or "
                f"elements, which a remeshed run replaces: with [remesh] use one of "
                f"{', '.join(REMESH_OBJECTIVES)} (or set {TRIGGERS_OFF})"
            )
        if d["max_temperature_K"] > 0.0:
            raise ConfigError(
                "design.max_temperature_K > 0 reads each row's nodal temperatures, which a "
                "remeshed run keeps on different meshes: set it to 0 with [remesh]"
            )
    if groups is not None:
        _check_groups(cfg, list(groups), where)
    d = cfg["design"]
    name = d["objective"]
    if name == "die_fill" and not cfg.get("die", {}).get("closed"):
        raise ConfigError("design.objective = 'die_fill' needs die.closed = true")
    if name == "wear_depth" and not cfg.get("wear", {}).get("on"):
        raise ConfigError("design.objective = 'wear_depth' needs wear.on = true")
    if name == "side_straightness" and not ({"billet", "ring"} & set(cfg)):
        raise ConfigError(
            "design.objective = 'side_straightness' needs a [billet] or [ring] scene (a free side)"
        )
    coupled = cfg["thermal"]["model"] == "coupled"
    if name == "temperature_misfit" and not coupled:
        raise ConfigError("design.objective = 'temperature_misfit' needs thermal.model = 'coupled'")
    if d["max_temperature_K"] > 0.0 and not coupled:
        raise ConfigError("design.max_temperature_K > 0 needs thermal.model = 'coupled'")
    columns = {
        "force_misfit": ("stroke_mm", "force_N"),
        "shape_target": ("node", "r_mm", "z_mm"),
        "temperature_misfit": ("time_s", "mean_temperature_K"),
    }
    if name in columns:
        target = d["target_csv"]
        if not target:
            raise ConfigError(f"design.objective = {name!r} needs design.target_csv")
        _check_target_csv(target, columns[name])


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


def _check_groups(cfg: dict, groups: list[str], where: str) -> None:
    shown = (
        f"{where} = {groups!r}" if where.startswith("design.") else f"{where} {' '.join(groups)}"
    )
    if not groups:
        raise ConfigError(
            f"{shown}: name at least one design group, of {', '.join(GRADIENT_GROUPS)}"
        )
    for g in groups:
        if g not in GRADIENT_GROUPS:
            raise ConfigError(
                f"{shown}: {g!r} is not a design group; each must be one of "
                f"{', '.join(GRADIENT_GROUPS)}"
            )
        if "membrane" in cfg and g in ("friction", "speed", "die"):
            raise ConfigError(f"{shown}: {g!r} needs a die; a [membrane] scene has none")
    models = [die_friction(cfg, d)["model"] for d in friction_dies(cfg)] if "die" in cfg else []
    if "friction" in groups and not set(FRICTION_COEFFICIENT) & set(models):
        raise ConfigError(
            f"{shown}: 'friction' needs friction.model = 'coulomb' or 'shear', not "
            f"{cfg['friction']['model']!r} (or a die's own [<die>.friction] model)"
        )
    th = cfg["thermal"]
    if "thermal" in groups and (th["model"] != "coupled" or th["htc_die_W_m2K"] <= 0.0):
        raise ConfigError(
            f"{shown}: 'thermal' needs thermal.model = 'coupled' and thermal.htc_die_W_m2K > 0"
        )
    model = cfg["press"]["model"] if "press" in cfg else "speed"
    if model in ("screw", "hammer"):
        raise ConfigError(
            f"press.model = {model!r}: design and taylor-test run presses that follow "
            "time ('speed', 'crank'); differentiate blows with jaxform.blows.blow_run"
        )
    if "speed" in groups and model != "speed":
        raise ConfigError(
            f"{shown}: 'speed' needs press.model = 'speed' (a {model} press sets its own speed)"
        )
    if "speed" in groups and cfg["die"]["path_time_s"]:
        raise ConfigError(
            f"{shown}: 'speed' needs die.speed_mm_s; this scene moves the die along die.path_time_s"
        )
    if "preform" in groups and ("billet" not in cfg or cfg["mesh"]["file"]):
        raise ConfigError(
            f"{shown}: 'preform' needs a [billet] scene on the structured mesh (mesh.file = '')"
        )
