"""Scene set-up from a validated config: workpiece mesh, boundary sets, die, contact.

config --load_config--> dict --build_scene--> :class:`jaxform.simulate.Scene`

Workpieces (exactly one section in the config); billets and rings are half-height models
with the symmetry plane z = 0 (u_z = 0) and the top die pressing down on it:

* ``[billet]`` solid cylinder (axisymmetric) or block (plane strain): section
  [0, D/2] x [0, H/2]; the axis r = 0 has u_r = 0; candidates for contact: top + side.
* ``[ring]`` ring of outer/inner diameter D_o, D_i and height H: section
  [D_i/2, D_o/2] x [0, H/2]; candidates: top + outer + inner (both sides can fold onto
  the die).
* ``mesh.file`` replaces the generated section by a gmsh/meshio mesh whose physical
  groups name the sets: ``symmetry`` and ``top`` required, ``axis``, ``side``, ``inner``,
  ``outer`` optional.
* ``[block]`` plane-strain block [0, W] x [0, D] indented from the top (Prandtl's punch):
  symmetric about x = 0 (``axis``, u_x = 0) on a frictionless base (``base``, y = 0,
  u_y = 0); candidates: the top face; graded mesh (equal elements under the die). The
  stroke is the die travel itself (no mid-plane), ``die.reduction`` a fraction of D.
* ``[membrane]`` plane-strain panel with 4 straight edges (Cook's membrane), no die: one
  edge clamped (u = 0), a uniform dead traction with resultant ``load.force_*_N`` on another
  (:mod:`jaxform.loads`), ramped linearly over ``load.ramp_time_s``; the history records the
  displacement of the node nearest ``membrane.tip_mm`` (``tip``).

Die: ``die.profile_mm`` (or a flat die on the top face), moved along the path table or at
half the ram speed (the mid-plane is fixed, so the top die travels half the stroke).
The run ends when the ram stroke reaches ``die.reduction`` x the workpiece height.
"""

from __future__ import annotations

from dataclasses import replace

import jax.numpy as jnp
import numpy as np

from jaxform import mesh as meshing
from jaxform.assembly import Model, build_indices
from jaxform.config import ConfigError
from jaxform.contact import ContactLaw
from jaxform.dies import DieError, catmull_rom, check_profile, make_die, time_at_travel
from jaxform.formulations import Formulation
from jaxform.linear import choose_backend, klu_symbolic
from jaxform.loads import FacetLoad
from jaxform.materials import load_material
from jaxform.precision import require_x64
from jaxform.simulate import Inputs, Scene
from jaxform.solver import NewtonSettings, choose_method

FREE_SETS = ("top", "side", "outer", "inner")
# Dirichlet conditions by node set: the displacement components held at 0
FIXED_COMPONENTS = {"symmetry": (1,), "axis": (0,), "base": (1,), "clamped": (0, 1)}
# u_y dofs of this set carry the support reaction (for checks)
REACTION_SETS = ("symmetry", "base", "clamped")


def membrane_mesh(cfg: dict) -> meshing.Mesh:
    """Mapped mesh of the panel with sets ``clamped``, ``loaded`` and ``tip`` added."""
    mb, m = cfg["membrane"], cfg["mesh"]
    corners = np.asarray(mb["corners_mm"])
    try:
        mesh = meshing.mapped_quad(corners, m["nr"], m["nz"])
    except meshing.MeshError as err:
        raise ConfigError(f"membrane.corners_mm: {err}") from err
    tip = np.asarray(mb["tip_mm"]) if mb["tip_mm"] else corners[2]
    tip_node = int(np.argmin(np.sum((mesh.coords - tip) ** 2, axis=1)))
    edge = cfg["load"]["edge"]
    nodes = dict(
        mesh.node_sets,
        clamped=mesh.node_sets[mb["clamped_edge"]],
        loaded=mesh.node_sets[edge],
        tip=np.array([tip_node]),
    )
    facets = dict(mesh.facet_sets, loaded=mesh.facet_sets[edge])
    return meshing.Mesh(mesh.coords, mesh.elements, nodes, facets)


def workpiece_mesh(cfg: dict) -> tuple[meshing.Mesh, str]:
    m = cfg["mesh"]
    kind = next(k for k in ("ring", "block", "membrane", "billet") if k in cfg)
    if kind == "membrane":
        return membrane_mesh(cfg), kind
    if kind == "block":
        b = cfg["block"]
        try:
            return meshing.block(
                b["width_mm"],
                b["depth_mm"],
                b["fine_width_mm"],
                b["fine_depth_mm"],
                m["nr"],
                m["nz"],
                b["growth"],
            ), kind
        except meshing.MeshError as err:
            raise ConfigError(f"block: {err}") from err
    if m["file"]:
        try:
            mesh = meshing.read_mesh(m["file"])
        except (OSError, meshing.MeshError) as err:
            raise ConfigError(f"mesh.file = {m['file']!r}: {err}") from err
        for name in ("symmetry", "top"):
            if name not in mesh.node_sets:
                raise ConfigError(
                    f"mesh.file = {m['file']!r}: needs a physical group {name!r} "
                    f"(line cells); found {sorted(mesh.node_sets)}"
                )
        return mesh, kind
    if kind == "billet":
        b = cfg["billet"]
        return meshing.billet_quarter(
            0.5 * b["diameter_mm"], 0.5 * b["height_mm"], m["nr"], m["nz"]
        ), kind
    r = cfg["ring"]
    ri, ro = 0.5 * r["inner_diameter_mm"], 0.5 * r["outer_diameter_mm"]
    rect = meshing.rectangle(ro - ri, 0.5 * r["height_mm"], m["nr"], m["nz"], origin=(ri, 0.0))
    rename = {"left": "inner", "right": "outer", "bottom": "symmetry", "top": "top"}
    return meshing.Mesh(
        rect.coords,
        rect.elements,
        {rename[k]: v for k, v in rect.node_sets.items()},
        {rename[k]: v for k, v in rect.facet_sets.items()},
    ), kind


def die_profile(cfg: dict, top_z: float) -> np.ndarray:
    d = cfg["die"]
    if not d["profile_mm"]:
        return np.array([[0.0, top_z], [1.0, top_z]])  # flat, extended both ways
    try:
        pts = check_profile(np.asarray(d["profile_mm"]), "die.profile_mm")
        if d["profile_kind"] == "spline":
            pts = check_profile(catmull_rom(pts), "die.profile_mm (sampled spline)")
    except DieError as err:
        raise ConfigError(str(err)) from err
    if d["closed"] and abs(pts[0, 0]) > 1e-9:
        raise ConfigError(
            f"die.closed = true: die.profile_mm must start on the axis (r = 0), "
            f"got r = {pts[0, 0]:g} mm"
        )
    return pts


def die_path(cfg: dict, half_height: float) -> tuple[np.ndarray, np.ndarray, float]:
    """(times, travel of the top die, end time) for a run to the configured reduction.

    Half-height models (billet, ring): the top die travels half the ram stroke at half the
    ram speed; a block (no mid-plane) is indented by the die's whole travel and speed."""
    d = cfg["die"]
    target = d["reduction"] * half_height  # top-die travel; the ram stroke is twice it
    if d["path_time_s"]:
        times, travel = np.asarray(d["path_time_s"]), np.asarray(d["path_travel_mm"])
        try:
            t_end = time_at_travel(times, travel, target, "die.path_travel_mm")
        except DieError as err:
            raise ConfigError(str(err)) from err
        return times, travel, t_end
    v = (1.0 if "block" in cfg else 0.5) * d["speed_mm_s"]
    t_end = target / v
    return np.array([0.0, t_end]), np.array([0.0, v * t_end]), t_end


def membrane_load(cfg: dict, mesh: meshing.Mesh) -> FacetLoad:
    """The traction (per unit initial edge length) whose resultant is load.force_*_N."""
    ld = cfg["load"]
    facets = mesh.facet_sets["loaded"]
    length = float(
        np.sum(np.linalg.norm(mesh.coords[facets[:, 1]] - mesh.coords[facets[:, 0]], axis=1))
    )
    traction = np.array([ld["force_x_N"], ld["force_y_N"]]) / length
    return FacetLoad(traction=jnp.asarray(traction), ramp_end_s=jnp.asarray(ld["ramp_time_s"]))


def build_scene(cfg: dict) -> Scene:
    """Set-up of a scene from a validated config: mesh, material, die or load, solver.

    Arguments:
        cfg: a config from :func:`jaxform.config.load_config` (every key present).

    Returns:
        the :class:`jaxform.simulate.Scene` (nothing compiled yet).

    Raises:
        ConfigError: a bad material preset or file, or a mesh file that does not fit.
    """
    require_x64()
    m, tm, so = cfg["mesh"], cfg["time"], cfg["solver"]
    axi = m["geometry"] == "axisymmetric"
    mesh, kind = workpiece_mesh(cfg)
    law, params = load_material(cfg["material"]["preset"])
    form = Formulation(
        kind=m["element"], axisymmetric=axi, theta=m["stabilization"], alpha=tm["alpha"]
    )
    nf = form.n_fields
    fixed = [
        mesh.node_sets[s] * nf + k
        for s, comps in FIXED_COMPONENTS.items()
        if s in mesh.node_sets
        for k in comps
    ]
    reaction = next(mesh.node_sets[s] * nf + 1 for s in REACTION_SETS if s in mesh.node_sets)
    if kind == "membrane":
        contact = np.zeros(0, dtype=np.int64)
        facets = np.zeros((0, 2), dtype=np.int64)
    else:
        present = ["top"] if kind == "block" else [s for s in FREE_SETS if s in mesh.node_sets]
        contact = np.unique(np.concatenate([mesh.node_sets[s] for s in present])).astype(np.int64)
        facets = np.concatenate([mesh.facet_sets[s] for s in present if s in mesh.facet_sets])
    layout, idx = build_indices(
        mesh,
        nf,
        np.concatenate(fixed),
        contact,
        reaction_dofs=reaction,
        contact_facets=facets,
        load_facets=mesh.facet_sets.get("loaded"),
    )
    fr = cfg.get("friction", {"model": "none", "mu": 0.0, "m": 0.0})
    model = Model(form, law, layout, ContactLaw(fr["model"]))
    areas = meshing.element_areas(mesh.coords, mesh.elements)
    if np.any(areas <= 0):
        raise ConfigError(
            "mesh: an element has non-positive area (check mesh.file or the billet profile)"
        )
    h = float(np.sqrt(areas.min()))
    r_out = float(mesh.coords[:, 0].max())
    c = float(law.shear_modulus(params)) * h * (2.0 * np.pi * r_out if axi else 1.0)
    if kind == "membrane":
        die, load, t_end = None, membrane_load(cfg, mesh), cfg["load"]["ramp_time_s"]
    else:
        top_z = float(mesh.coords[mesh.node_sets["top"], 1].max())
        times, travel, t_end = die_path(cfg, top_z)
        die = make_die(
            die_profile(cfg, top_z),
            times,
            travel,
            mu=fr["mu"],
            m=fr["m"],
            corner_radius=cfg["die"]["corner_radius_mm"],
        )
        load = None
    structured = kind in ("billet", "ring") and not m["file"]
    if m["rezone_quality"] > 0.0 and not structured:
        raise ConfigError(
            f"mesh.rezone_quality > 0 needs a billet or ring scene on its "
            f"structured mesh (this scene: {kind})"
        )
    linear = choose_backend(so["linear"], layout.n_dofs)
    try:
        method = choose_method(so["newton"], linear.backend, layout.n_dofs)
    except ValueError as err:
        raise ConfigError(str(err)) from None
    if linear.backend == "sparse":  # KLU's symbolic analysis once per pattern, outside jit
        idx = replace(idx, lu_symbolic=klu_symbolic(idx.rows, idx.cols, layout.n_dofs))
    return Scene(
        config=cfg,
        mesh=mesh,
        model=model,
        idx=idx,
        linear=linear,
        newton=NewtonSettings(
            max_iterations=so["max_newton_iterations"],
            rtol=so["rtol"],
            line_search=so["line_search"],
            method=method,
        ),
        inputs=Inputs(
            coords=jnp.asarray(mesh.coords),
            params=params,
            die=die,
            c_contact=jnp.asarray(c),
            load=load,
        ),
        dt=tm["dt_s"],
        t_end=t_end,
        max_cutbacks=so["max_cutbacks"],
        dt_growth=tm["dt_growth"],
        chunk=so["chunk_steps"],
        kind=kind,
        symmetric_z=kind in ("billet", "ring"),
        rezone_quality=m["rezone_quality"],
        grid=(m["nr"], m["nz"]) if structured else None,
        adjoint_memory_mb=so["adjoint_memory_mb"],
    )
