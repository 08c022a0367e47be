"""The config sections of the workpiece and its mesh: [billet], [ring], [block],
[membrane] and its [load], [mesh], [remesh], [material].  This module imports no JAX."""

from __future__ import annotations

from dataclasses import dataclass

from jaxform.config.schema import MAX_FORCE_N, key, section

FULL_HEIGHT_DOC = (
    "model the whole height, z in [-H/2, H/2], between the top die [die] and a bottom die "
    "[bottom_die] (no mid-plane; mesh.nz counts the elements over the whole height): for "
    "parts whose top and bottom differ. false: the half above the mid-plane z = 0"
)


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
        "thickness (a flash, a thin web), down to a quarter of the die size (0 = off)",
    )
    from_start: bool = key(
        False,
        doc="the run starts on the remesher's own mesh of the workpiece section (gmsh, "
        "remesh.element_size_mm, finer where a die touches it at t = 0) instead of its "
        "structured grid, so that a remesh does not change the mesh's resolution; needs "
        "a remesh trigger",
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

    @property
    def off_keys(self) -> str:
        """The keys that turn every trigger off, for messages (``remesh.quality_below = 0,
        ...``)."""
        return TRIGGERS_OFF


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
