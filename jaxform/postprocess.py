"""Host-side quantities derived from converged states (NumPy): what engineers read.

* ring scenes: ``inner_diameter_mm`` and ``outer_diameter_mm`` at the ring's mid-height
  (the nodes of the inner/outer surface on the symmetry plane);
* closed dies: ``die_fill`` = material volume / volume of the cavity enclosed by the
  (rounded, :mod:`jaxform.dies`) die profile, the axis and the mid-plane (Pappus:
  V = 2 pi * integral of r dA);
* contact profiles along the die: normal pressure and shear traction (multiplier over
  the node's contact area, MPa), status (0 open, 1 stick, 2 slip), accumulated slip.
"""

from __future__ import annotations

import numpy as np

from jaxform.dies import sample_rounded
from jaxform.io import nodal_fields


def positions(scene, x) -> np.ndarray:
    u, _, _ = nodal_fields(scene, x)
    return np.asarray(scene.mesh.coords) + u


def _mid_height_node(scene, name: str) -> int:
    nodes = np.intersect1d(scene.mesh.node_sets[name], scene.mesh.node_sets["symmetry"])
    return int(nodes[0])


def _revolved(poly: np.ndarray, axisymmetric: bool) -> float:
    """Volume of revolution (axisymmetric) or area (plane strain) of a closed polygon."""
    x, y = poly[:, 0], poly[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    if axisymmetric:
        return abs(2.0 * np.pi * np.sum(cross * (x + xn)) / 6.0)
    return abs(0.5 * np.sum(cross))


def material_volume(scene, pos: np.ndarray) -> float:
    axi = scene.model.formulation.axisymmetric
    return sum(_revolved(pos[e], axi) for e in np.asarray(scene.mesh.elements))


def _clip_above(poly: np.ndarray, z0: float = 0.0) -> np.ndarray:
    """Sutherland-Hodgman clip of a closed polygon to the half-plane z >= z0."""
    out = []
    for a, b in zip(poly, np.roll(poly, -1, axis=0)):
        ina, inb = a[1] >= z0, b[1] >= z0
        if ina:
            out.append(a)
        if ina != inb:
            s = (z0 - a[1]) / (b[1] - a[1])
            out.append(a + s * (b - a))
    return np.array(out) if out else np.zeros((0, 2))


def cavity_volume(scene, t: float) -> float:
    die = scene.inputs.die
    pts = sample_rounded(die.points, die.corner_radius) - np.array([0.0, float(die.travel(t))])
    poly = np.vstack([[0.0, 0.0], pts, [pts[-1, 0], 0.0]])
    poly = _clip_above(poly)
    if len(poly) < 3:
        return 0.0
    return _revolved(poly, scene.model.formulation.axisymmetric)


def extra_history(scene, xs: np.ndarray, times: np.ndarray) -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    if scene.kind == "ring":
        ki, ko = _mid_height_node(scene, "inner"), _mid_height_node(scene, "outer")
        pos = [positions(scene, x) for x in xs]
        out["inner_diameter_mm"] = np.array([2.0 * p[ki, 0] for p in pos])
        out["outer_diameter_mm"] = np.array([2.0 * p[ko, 0] for p in pos])
    if scene.config["die"]["closed"]:
        out["die_fill"] = np.array([
            material_volume(scene, positions(scene, x)) / max(cavity_volume(scene, t), 1e-300)
            for x, t in zip(xs, times)])
    return out


def contact_profile(scene, x: np.ndarray, slip_mm: np.ndarray, status: np.ndarray) -> dict:
    """Per candidate node (sorted along the die by arc position): position, pressure and
    shear traction (MPa), status, accumulated slip (mm)."""
    import jax.numpy as jnp

    from jaxform.contact import tributary_areas

    idx = scene.idx
    pos = positions(scene, x)[np.asarray(idx.contact_nodes)]
    lay = scene.model.layout
    lam = np.asarray(x[lay.n_node_dofs:]).reshape(-1, 2)
    area = np.asarray(tributary_areas(jnp.asarray(pos), idx.contact_facets,
                                      scene.model.formulation.axisymmetric))
    safe = np.where(area > 0, area, 1.0)
    return dict(r_mm=pos[:, 0], z_mm=pos[:, 1], pressure_MPa=lam[:, 0] / safe,
                shear_MPa=lam[:, 1] / safe, status=np.asarray(status),
                slip_mm=np.asarray(slip_mm), area_mm2=area)
