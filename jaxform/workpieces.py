"""Workpieces: what each kind of workpiece section knows about itself.

One class per workpiece section of a config (``[billet]``, ``[ring]``, ``[block]``,
``[membrane]``, and a ``mesh.file`` that replaces a billet's or ring's generated section).
A workpiece builds its section mesh with named node and facet sets, says which sets a die
may touch, how the die's travel relates to the ram stroke, what the reduction refers to,
which extra history columns a run records, which design groups apply and how plots label
it.  The rest of jaxform asks the workpiece instead of branching on the section's name.

Billets and rings are half-height models with the symmetry plane z = 0 (u_z = 0) and the
top die pressing down on it: the die travels half the ram stroke at half the ram speed.
With ``full_height`` they span z in [-H/2, H/2] between a top and a bottom die (sets
``bottom`` instead of ``symmetry``; the stroke is the dies' closure).

* :class:`Billet`: solid cylinder (axisymmetric) or block (plane strain), section
  [0, D/2] x [0, H/2]; the axis r = 0 has u_r = 0; contact candidates: top + side.
* :class:`Ring`: section [D_i/2, D_o/2] x [0, H/2]; candidates: top + outer + inner (both
  sides can fold onto the die); the history records the inner and outer diameters.
* :class:`MeshFile`: a gmsh/meshio section whose physical groups name the sets:
  ``symmetry`` (full height: ``bottom``) and ``top`` required, ``axis``, ``side``,
  ``inner``, ``outer`` optional.
* :class:`Block`: plane-strain block [0, W] x [0, D] indented from the top (Prandtl's
  punch): symmetric about x = 0 (``axis``, u_x = 0) on a frictionless base (``base``,
  y = 0, u_y = 0); candidates: the top face; graded mesh (equal elements under the die).
  The stroke is the die travel itself, ``die.reduction`` a fraction of the depth.
* :class:`Membrane`: plane-strain panel with 4 straight edges (Cook's membrane), no die:
  one edge clamped (u = 0), a uniform dead traction on another; the history records the
  displacement of the node nearest ``membrane.tip_mm`` (``tip_ux_mm``, ``tip_uy_mm``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from jaxform import mesh as meshing
from jaxform.config import GRADIENT_GROUPS, Config, MeshConfig
from jaxform.errors import ConfigError

# the sets a die may touch, by name (a workpiece uses those its mesh has)
FREE_SETS = ("top", "side", "outer", "inner", "bottom")
# the design groups of scenes pressed by a die (preform: billets on their generated mesh)
DIE_GROUPS = GRADIENT_GROUPS


@dataclass(frozen=True)
class Workpiece(ABC):
    """What every workpiece answers (the defaults are those of a half-height model)."""

    name: ClassVar[str]
    half_height: ClassVar[bool] = True  # mid-plane z = 0 held: ram stroke = 2 x die travel
    pressed: ClassVar[bool] = True  # pressed by a die (a membrane is loaded instead)

    @abstractmethod
    def build_mesh(self) -> meshing.Mesh:
        """The section mesh with its named node and facet sets."""

    def contact_sets(self, mesh: meshing.Mesh) -> tuple[str, ...]:
        """The sets whose nodes and facets a die may touch."""
        return tuple(s for s in FREE_SETS if s in mesh.node_sets)

    @property
    @abstractmethod
    def reference_height_mm(self) -> float:
        """The height ``die.reduction`` refers to (mm)."""

    @property
    def grid(self) -> tuple[int, int] | None:
        """(nr, nz) of a structured mesh that rezoning can relocate, or None."""
        return None

    def design_groups(self) -> tuple[str, ...]:
        """The design groups that apply (before the friction law is asked)."""
        return tuple(g for g in DIE_GROUPS if g != "preform")

    def extra_history(self, mesh: meshing.Mesh, positions, displacements) -> dict:
        """History columns of this workpiece on ``mesh`` (its sets) from the nodal
        positions and displacements of every row ((rows, nodes, 2) arrays, mm)."""
        return {}


class _Generated(Workpiece):
    """A billet or ring on its generated structured mesh: the reduction refers to its
    height, and rezoning may relocate the nodes of its (nr, nz) grid.  Full height: the
    section spans z in [-H/2, H/2] with a ``bottom`` set (a bottom die's candidates) in
    place of the mid-plane ``symmetry``."""

    height_mm: float
    mesh: MeshConfig
    full_height: bool

    @property
    def half_height(self) -> bool:
        return not self.full_height

    @property
    def reference_height_mm(self) -> float:
        return self.height_mm

    @property
    def grid(self) -> tuple[int, int] | None:
        return None if self.full_height else (self.mesh.nr, self.mesh.nz)

    def _rectangle(self, r0: float, r1: float, names: dict[str, str]) -> meshing.Mesh:
        """The structured section [r0, r1] x [0, H/2] (full height: [-H/2, H/2]) with the
        rectangle's sets renamed by ``names`` (left/right/bottom/top)."""
        h, m = self.height_mm, self.mesh
        z0 = -0.5 * h if self.full_height else 0.0
        rect = meshing.rectangle(r1 - r0, -z0 + 0.5 * h, m.nr, m.nz, origin=(r0, z0))
        names = dict(names, bottom="bottom" if self.full_height else "symmetry")
        return meshing.Mesh(
            rect.coords,
            rect.elements,
            {names[k]: v for k, v in rect.node_sets.items()},
            {names[k]: v for k, v in rect.facet_sets.items()},
        )


def _mid_height_node(mesh: meshing.Mesh, name: str) -> int:
    """The node of set ``name`` on the symmetry plane, or (full height) the one nearest
    the set's mid-height (the workpiece's mid-height)."""
    nodes = mesh.node_sets[name]
    if "symmetry" in mesh.node_sets:
        return int(np.intersect1d(nodes, mesh.node_sets["symmetry"])[0])
    z = mesh.coords[nodes, 1]
    return int(nodes[np.argmin(np.abs(z - 0.5 * (z.min() + z.max())))])


@dataclass(frozen=True)
class Billet(_Generated):
    diameter_mm: float
    height_mm: float
    mesh: MeshConfig
    full_height: bool = False
    name: ClassVar[str] = "billet"

    def build_mesh(self) -> meshing.Mesh:
        if self.full_height:
            return self._rectangle(0.0, 0.5 * self.diameter_mm, dict(left="axis", right="side",
                                                                     top="top"))  # fmt: skip
        return meshing.billet_quarter(
            0.5 * self.diameter_mm, 0.5 * self.height_mm, self.mesh.nr, self.mesh.nz
        )

    def design_groups(self) -> tuple[str, ...]:
        return DIE_GROUPS


@dataclass(frozen=True)
class Ring(_Generated):
    outer_diameter_mm: float
    inner_diameter_mm: float
    height_mm: float
    mesh: MeshConfig
    full_height: bool = False
    name: ClassVar[str] = "ring"

    def build_mesh(self) -> meshing.Mesh:
        ri, ro = 0.5 * self.inner_diameter_mm, 0.5 * self.outer_diameter_mm
        return self._rectangle(ri, ro, dict(left="inner", right="outer", top="top"))

    def extra_history(self, mesh: meshing.Mesh, positions, displacements) -> dict:
        if not {"inner", "outer"} <= set(mesh.node_sets):
            return {}
        ki, ko = _mid_height_node(mesh, "inner"), _mid_height_node(mesh, "outer")
        return {
            "inner_diameter_mm": 2.0 * positions[:, ki, 0],
            "outer_diameter_mm": 2.0 * positions[:, ko, 0],
        }


@dataclass(frozen=True)
class MeshFile(Workpiece):
    """A billet or ring section read from a mesh file (``mesh.file``)."""

    path: str
    base: Billet | Ring  # the section the file replaces (its height for the reduction)
    name: ClassVar[str] = "mesh file"

    def build_mesh(self) -> meshing.Mesh:
        try:
            mesh = meshing.read_mesh(self.path)
        except (OSError, meshing.MeshError) as err:
            raise ConfigError(f"mesh.file = {self.path!r}: {err}") from err
        for name in ("bottom" if self.base.full_height else "symmetry", "top"):
            if name not in mesh.node_sets:
                raise ConfigError(
                    f"mesh.file = {self.path!r}: needs a physical group {name!r} "
                    f"(line cells); found {sorted(mesh.node_sets)}"
                )
        return mesh

    @property
    def half_height(self) -> bool:
        return self.base.half_height

    @property
    def reference_height_mm(self) -> float:
        return self.base.reference_height_mm

    def extra_history(self, mesh: meshing.Mesh, positions, displacements) -> dict:
        return self.base.extra_history(mesh, positions, displacements)


@dataclass(frozen=True)
class Block(Workpiece):
    width_mm: float
    depth_mm: float
    fine_width_mm: float
    fine_depth_mm: float
    growth: float
    mesh: MeshConfig
    name: ClassVar[str] = "block"
    half_height: ClassVar[bool] = False  # no mid-plane: the stroke is the die travel

    def build_mesh(self) -> meshing.Mesh:
        try:
            return meshing.block(
                self.width_mm,
                self.depth_mm,
                self.fine_width_mm,
                self.fine_depth_mm,
                self.mesh.nr,
                self.mesh.nz,
                self.growth,
            )
        except meshing.MeshError as err:
            raise ConfigError(f"block: {err}") from err

    def contact_sets(self, mesh: meshing.Mesh) -> tuple[str, ...]:
        return ("top",)

    @property
    def reference_height_mm(self) -> float:
        return self.depth_mm


@dataclass(frozen=True)
class Membrane(Workpiece):
    corners_mm: tuple[tuple[float, float], ...]
    clamped_edge: str
    tip_mm: tuple[float, ...]
    loaded_edge: str
    mesh: MeshConfig
    name: ClassVar[str] = "membrane"
    half_height: ClassVar[bool] = False
    pressed: ClassVar[bool] = False

    def build_mesh(self) -> meshing.Mesh:
        """Mapped mesh of the panel with sets ``clamped``, ``loaded`` and ``tip`` added."""
        corners = np.asarray(self.corners_mm)
        try:
            mesh = meshing.mapped_quad(corners, self.mesh.nr, self.mesh.nz)
        except meshing.MeshError as err:
            raise ConfigError(f"membrane.corners_mm: {err}") from err
        tip = np.asarray(self.tip_mm) if self.tip_mm else corners[2]
        tip_node = int(np.argmin(np.sum((mesh.coords - tip) ** 2, axis=1)))
        nodes = dict(
            mesh.node_sets,
            clamped=mesh.node_sets[self.clamped_edge],
            loaded=mesh.node_sets[self.loaded_edge],
            tip=np.array([tip_node]),
        )
        facets = dict(mesh.facet_sets, loaded=mesh.facet_sets[self.loaded_edge])
        return meshing.Mesh(mesh.coords, mesh.elements, nodes, facets)

    def contact_sets(self, mesh: meshing.Mesh) -> tuple[str, ...]:
        return ()

    @property
    def reference_height_mm(self) -> float:
        return float(np.ptp(np.asarray(self.corners_mm)[:, 1]))

    def design_groups(self) -> tuple[str, ...]:
        return ()

    def extra_history(self, mesh: meshing.Mesh, positions, displacements) -> dict:
        k = int(mesh.node_sets["tip"][0])
        return {"tip_ux_mm": displacements[:, k, 0], "tip_uy_mm": displacements[:, k, 1]}


def workpiece_of(cfg: Config) -> Workpiece:
    """The workpiece of a typed config: the one place that reads its workpiece section."""
    m = cfg.mesh
    if cfg.membrane is not None:
        mb = cfg.membrane
        return Membrane(mb.corners_mm, mb.clamped_edge, mb.tip_mm, cfg.load.edge, m)
    if cfg.block is not None:
        b = cfg.block
        return Block(b.width_mm, b.depth_mm, b.fine_width_mm, b.fine_depth_mm, b.growth, m)
    if cfg.ring is not None:
        r = cfg.ring
        base = Ring(r.outer_diameter_mm, r.inner_diameter_mm, r.height_mm, m, r.full_height)
    else:
        b = cfg.billet
        base = Billet(b.diameter_mm, b.height_mm, m, b.full_height)
    return MeshFile(m.file, base) if m.file else base
