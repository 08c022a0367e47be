"""The config sections of the dies and what acts between them and the workpiece: [die],
[press], [bottom_die], [side_die], [friction], [wear], [thermal].  This module imports
no JAX."""

from __future__ import annotations

from dataclasses import dataclass

from jaxform.config.schema import key, section


def _profile_kind_key():
    return key(
        "polyline",
        choices=("polyline", "spline"),
        doc="straight segments between the points, or the Catmull-Rom spline through them",
    )


def _corner_radius_key(doc: str):
    return key(0.5, low=0.0, low_open=True, doc=doc)


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
    contact_pairs: str = key(
        "nearest",
        choices=("nearest", "each_die"),
        doc="with several dies: 'nearest', each workpiece node faces the die with the least "
        "gap (one multiplier pair per node); 'each_die', one multiplier pair per node and "
        "die, each with that die's friction law, so a node pressed into the corner of two "
        "dies (a container wall and the punch or the bottom die) carries both dies' forces "
        "(more unknowns: the contact nodes times the dies)",
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
        doc="shear friction factor, tau = m sigma_eq/sqrt(3) where the contact pressure "
        "reaches 0.05 sigma_eq, less below it (friction.model = shear)",
    )


# the die sections that may hold their own friction law, a [<die>.friction] sub-table
FRICTION_DIES = ("die", "bottom_die", "side_die")


@dataclass(frozen=True, kw_only=True)
class DieFrictionConfig:
    """[die.friction], [bottom_die.friction], [side_die.friction]: that die's own friction
    law; a key left out takes [friction]'s (:func:`jaxform.config.document.die_friction`).
    The one class serves the three tables (:data:`jaxform.config.document.SECTIONS`)."""

    model: str | None = key(
        choices=FRICTION_MODELS, doc="this die's friction law (default: friction.model)"
    )
    mu: float | None = key(
        low=0.0, high=10.0, doc="this die's Coulomb coefficient (default: friction.mu)"
    )
    m: float | None = key(low=0.0, high=1.0, doc="this die's shear factor (default: friction.m)")


# keys with no default that take [friction]'s value where left out
INHERITED = {(f"{d}.friction", k) for d in FRICTION_DIES for k in ("model", "mu", "m")}


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
