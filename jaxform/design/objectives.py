"""Design objectives: pure functions of a differentiable run (:class:`Trajectory`).

Each objective is a small immutable object holding its set-up constants (node or element
sets, targets) with ``__call__(traj, inputs) -> scalar`` (``inputs`` = the run's inputs)
(traceable, differentiable) and a
``unit``/``describe`` for reports.  Built from a scene and the config by
:func:`jaxform.design.problem.build_objective`.

* :class:`SideStraightness`  mean squared deviation (mm^2) of the final free-side radii
  from their mean: 0 for a straight cylindrical side (preform design against bulging).
* :class:`ShapeTarget`       mean squared distance (mm^2) of chosen final node positions
  from target positions.
* :class:`PeakForce`         the largest ram force of the history (N).
* :class:`ForgingWork`       integral of force over stroke (N mm, trapezoid rule).
* :class:`ForceMisfit`       relative L2 misfit of the force-stroke curve against a target
  curve (material identification): sum (F(s_i) - F_i)^2 / sum F_i^2 at the target
  strokes, F(s) interpolated linearly in the run's history.
* :class:`EqpsSpread`        variance of the element-mean equivalent plastic strain over
  a set of elements.
* :class:`UnfilledCavity`    1 - material volume / cavity volume at the end (0 = filled):
  the cavity enclosed by the die profile (its corners rounded, as the history's
  ``die_fill`` measures it), the axis and the mid-plane.
* :class:`TemperatureMisfit` mean squared difference (K^2) of the run's mean temperature
  (weighted by the material each node carries) from a target history, interpolated in time
  (coupled thermal runs: identification of a conductance).
* :class:`MaxDamage`         a smooth maximum of a ductile damage integral over the Gauss
  points at the end of the run (:mod:`jaxform.damage`): the power mean
  (mean over the points of max(D, 0)^p)^(1/p), which lies between N^(-1/p) max D and
  max D (N points) and tends to max D as p grows.
* :class:`WearDepth`         the same smooth maximum of the Archard wear depth (mm) over
  every die's stations at the end of the run (:mod:`jaxform.wear`).
* :class:`FlashVolume`      the material beyond a radius at the end (mm^3; both halves
  of a half-height model): each element clipped to r >= radius, measured as a polygon
  (:func:`measure_beyond`); continuous with continuous derivatives in the positions.
* :class:`PressCapacity`    weight x (max(0, F_peak - capacity) / capacity)^2: a
  penalty on the peak ram force above the press's capacity.
* :class:`LapPenalty`       sum over the free-surface vertices of (max(0, 1 - a / a_lap))^2,
  a the air-side wedge angle there at the end (the differentiable form of the wedge of
  :mod:`jaxform.laps`, a lap: 180 deg on a straight side, 0 when the surface has folded
  onto itself; pockets, air between the material and a die, do not enter it).
* :class:`WeightedSum`      sum of weights x terms (any of the above); ``values`` lists
  each term's value for the report.
* :class:`TemperatureLimit`  another objective plus a quadratic penalty on the hottest node
  above a limit: weight x sum over the rows of max(0, T_max - limit)^2 (an exterior penalty:
  the limit holds approximately, better as the weight grows).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

from jaxform.design.parametrize import workpiece_volume
from jaxform.dies import rounded_polyline
from jaxform.fill import slivers
from jaxform.geometry import polygon_measure
from jaxform.mesh import boundary_edges


class _Identity:
    def __hash__(self):  # set-up arrays inside: identity is enough
        return id(self)


@dataclass(frozen=True, eq=False)
class SideStraightness(_Identity):
    side_nodes: np.ndarray
    unit = "mm^2"

    def __call__(self, traj, inputs):
        r = traj.positions[self.side_nodes, 0]
        return jnp.mean((r - jnp.mean(r)) ** 2)


@dataclass(frozen=True, eq=False)
class ShapeTarget(_Identity):
    nodes: np.ndarray
    target_mm: np.ndarray  # (len(nodes), 2)
    unit = "mm^2"

    def __call__(self, traj, inputs):
        d = traj.positions[self.nodes] - jnp.asarray(self.target_mm)
        return jnp.mean(jnp.sum(d * d, axis=1))


@dataclass(frozen=True, eq=False)
class PeakForce(_Identity):
    unit = "N"

    def __call__(self, traj, inputs):
        return jnp.max(traj.force_N)


@dataclass(frozen=True, eq=False)
class ForgingWork(_Identity):
    unit = "N mm"

    def __call__(self, traj, inputs):
        s, f = traj.stroke_mm, traj.force_N
        return jnp.sum(0.5 * (f[1:] + f[:-1]) * (s[1:] - s[:-1]))


@dataclass(frozen=True, eq=False)
class ForceMisfit(_Identity):
    stroke_mm: np.ndarray
    force_N: np.ndarray
    unit = "-"

    def __call__(self, traj, inputs):
        f = jnp.interp(jnp.asarray(self.stroke_mm), traj.stroke_mm, traj.force_N)
        target = jnp.asarray(self.force_N)
        return jnp.sum((f - target) ** 2) / jnp.sum(target**2)


@dataclass(frozen=True, eq=False)
class EqpsSpread(_Identity):
    elements: np.ndarray  # element ids of the region
    unit = "-"

    def __call__(self, traj, inputs):
        e = jnp.mean(traj.gauss.mat.eqps[self.elements], axis=1)
        return jnp.var(e)


def _cavity_polygon(points, travel, corner_radius):
    """The cavity's outline, clockwise: the axis at the mid-plane, the die profile (its
    corners rounded by ``corner_radius`` as the contact sees them,
    :func:`jaxform.dies.rounded_polyline`; sharp where None) moved down by ``travel``,
    its last point's foot on the mid-plane.  The part of the profile below z = 0 is
    clipped by clamping, exact for profiles that cross z = 0 only at their last segment."""
    pts = die_surface(points, travel, corner_radius)
    pts = pts.at[:, 1].set(jnp.maximum(pts[:, 1], 0.0))
    return jnp.concatenate(
        [jnp.zeros((1, 2), pts.dtype), pts, jnp.stack([pts[-1, 0], 0.0])[None, :]], axis=0
    )


def die_surface(points, travel, corner_radius):
    """The die's surface moved down by ``travel``, its corners rounded as the contact
    sees them (:func:`jaxform.dies.rounded_polyline`; traceable)."""
    pts = points if corner_radius is None else rounded_polyline(points, corner_radius)
    return pts - jnp.stack([0.0, travel])[None, :]


def conformed_change(pos, elements, surface, axisymmetric: bool, radius=None):
    """What the material's measure gains where its boundary edges conform to the die
    ``surface`` (:mod:`jaxform.fill`): each sliver between a chord and a concave die path,
    less each overlap of a convex one; with ``radius`` its part at r <= radius.  The
    boundary edges are the mesh's (``elements``, static).  Traceable."""
    conformed, polys = slivers(pos, boundary_edges(np.asarray(elements)), surface)
    change = polygon_measure(polys, axisymmetric)
    if radius is not None:
        change = change - polygon_measure_beyond(polys, radius, axisymmetric)
    return jnp.sum(jnp.where(conformed, change, 0.0))


def cavity_volume(points, travel, axisymmetric: bool, corner_radius=None):
    """Volume (or area) between a die profile moved down by ``travel``, the axis r = 0 and
    the mid-plane z = 0 (traceable; :func:`_cavity_polygon`)."""
    poly = _cavity_polygon(points, travel, corner_radius)
    return jnp.abs(polygon_measure(poly, axisymmetric))


@dataclass(frozen=True, eq=False)
class UnfilledCavity(_Identity):
    """1 - die fill at the end of the run."""

    elements: np.ndarray
    axisymmetric: bool
    unit = "-"

    def __call__(self, traj, inputs):
        die = inputs.die
        vol = workpiece_volume(traj.positions, self.elements, self.axisymmetric)
        t = traj.time_s[-1]
        surface = die_surface(die.points, die.travel(t), die.corner_radius)
        vol = vol + conformed_change(traj.positions, self.elements, surface, self.axisymmetric)
        cav = cavity_volume(die.points, die.travel(t), self.axisymmetric, die.corner_radius)
        return 1.0 - vol / cav


@dataclass(frozen=True, eq=False)
class TemperatureMisfit(_Identity):
    time_s: np.ndarray  # target times (s)
    temperature_K: np.ndarray  # target mean temperatures (K)
    weights: np.ndarray  # (n_nodes,) the material each node carries (mm^3)
    unit = "K^2"

    def __call__(self, traj, inputs):
        w = jnp.asarray(self.weights)
        mean = traj.temperature_K @ w / jnp.sum(w)
        at = jnp.interp(jnp.asarray(self.time_s), traj.time_s, mean)
        return jnp.mean((at - jnp.asarray(self.temperature_K)) ** 2)


def power_mean(values, p: float):
    """(mean of max(v, 0)^p)^(1/p): a smooth maximum of non-negative values, between
    N^(-1/p) max and max; finite derivatives where every value is 0 (the 1e-300 floor
    inside the root moves the value by at most 1e-300^(1/p))."""
    v = jnp.maximum(jnp.ravel(values), 0.0)
    return (jnp.mean(v**p) + 1e-300) ** (1.0 / p)


@dataclass(frozen=True, eq=False)
class MaxDamage(_Identity):
    criterion: int  # index in jaxform.damage.CRITERIA
    p: float = 8.0
    unit = "-"

    def __call__(self, traj, inputs):
        return power_mean(traj.final_state.damage[..., self.criterion], self.p)


@dataclass(frozen=True, eq=False)
class WearDepth(_Identity):
    p: float = 8.0
    unit = "mm"

    def __call__(self, traj, inputs):
        return power_mean(traj.final_state.wear_mm, self.p)


@dataclass(frozen=True, eq=False)
class TemperatureLimit(_Identity):
    inner: object  # the objective to minimize
    limit_K: float
    weight: float  # objective units per K^2

    @property
    def unit(self):
        return self.inner.unit

    def __call__(self, traj, inputs):
        over = jnp.maximum(jnp.max(traj.temperature_K, axis=1) - self.limit_K, 0.0)
        return self.inner(traj, inputs) + self.weight * jnp.sum(over**2)


def measure_beyond(pos, elements, radius: float, axisymmetric: bool):
    """(n_el,) measure (volume of revolution or area) of each element clipped to
    r >= radius (traceable).  Each edge contributes its start vertex and, where it
    crosses r = radius, the crossing; every vertex is then moved onto the line where it
    lies inside r < radius.  Along the line the boundary integral of the measure depends
    only on its end points, so the moved polygon has exactly the clipped element's
    measure; the measure is continuous with continuous derivatives (a vertex that
    crosses the line adds a sliver quadratic in its distance)."""
    p = pos[jnp.asarray(elements)]  # (e, 4, 2)
    q = jnp.roll(p, -1, axis=1)
    a, b = p[..., 0] - radius, q[..., 0] - radius
    cross = a * b < 0.0
    t = jnp.where(cross, -a / jnp.where(cross, b - a, 1.0), 0.0)
    x = p + t[..., None] * (q - p)
    poly = jnp.stack([p, x], axis=2).reshape(p.shape[0], 8, 2)
    poly = poly.at[..., 0].set(jnp.maximum(poly[..., 0], radius))
    return polygon_measure(poly, axisymmetric)


@dataclass(frozen=True, eq=False)
class FlashVolume(_Identity):
    """The material beyond ``radius_mm`` at the end of the run (mm^3 axisymmetric, mm^2
    per mm plane strain), times ``halves`` (2 for a half-height model)."""

    elements: np.ndarray
    radius_mm: float
    axisymmetric: bool
    halves: float = 2.0
    unit = "mm^3"

    def __call__(self, traj, inputs):
        m = measure_beyond(traj.positions, self.elements, self.radius_mm, self.axisymmetric)
        return self.halves * jnp.sum(m)


@dataclass(frozen=True, eq=False)
class PressCapacity(_Identity):
    """weight x (max(0, F_peak - capacity) / capacity)^2 (0 within the capacity)."""

    capacity_N: float
    weight: float = 1.0
    unit = "-"

    def __call__(self, traj, inputs):
        over = jnp.maximum(jnp.max(traj.force_N) - self.capacity_N, 0.0) / self.capacity_N
        return self.weight * over**2


@dataclass(frozen=True, eq=False)
class LapPenalty(_Identity):
    """sum of (max(0, 1 - a_i / limit))^2 over the free-surface vertices ``nodes`` (the
    boundary loop's, counter-clockwise, with ``prev`` and ``next`` their neighbours on
    it): a_i the air-side angle (rad) between the two edges at the end of the run."""

    prev: np.ndarray
    nodes: np.ndarray
    next: np.ndarray
    limit_rad: float
    unit = "-"

    def angles(self, positions):
        x = positions[jnp.asarray(self.nodes)]
        e_in = x - positions[jnp.asarray(self.prev)]
        e_out = positions[jnp.asarray(self.next)] - x
        cross = e_in[:, 0] * e_out[:, 1] - e_in[:, 1] * e_out[:, 0]
        return jnp.pi + jnp.arctan2(cross, jnp.sum(e_in * e_out, axis=1))

    def __call__(self, traj, inputs):
        a = self.angles(traj.positions)
        return jnp.sum(jnp.maximum(1.0 - a / self.limit_rad, 0.0) ** 2)


@dataclass(frozen=True, eq=False)
class WeightedSum(_Identity):
    """sum_i weights_i x terms_i(run); ``names`` label the terms in reports."""

    names: tuple[str, ...]
    terms: tuple
    weights: tuple[float, ...]
    unit = "-"

    def values(self, traj, inputs) -> dict:
        """{name: the term's value (its own unit)} (unweighted)."""
        return {n: t(traj, inputs) for n, t in zip(self.names, self.terms)}

    def __call__(self, traj, inputs):
        return sum(w * t(traj, inputs) for w, t in zip(self.weights, self.terms))


def _beyond_antiderivative(r, radius: float, axisymmetric: bool):
    """G with G' = f, f the integrand of the boundary integral of the material beyond
    ``radius`` (f = (r^2 - R^2) / 2 axisymmetric, r - R plane, both 0 for r < R)."""
    if axisymmetric:
        g = r**3 / 6.0 - radius**2 * r / 2.0 + radius**3 / 3.0
    else:
        g = 0.5 * (r - radius) ** 2
    return jnp.where(r > radius, g, 0.0)


def _edge_beyond(p, q, radius: float, axisymmetric: bool):
    """The integral of f(r) dz along the straight edges p -> q (..., 2): the divided
    difference (G(q_r) - G(p_r)) / (q_r - p_r) times the edge's dz, its Taylor form
    f(mid) (+ d^2 / 24 axisymmetric) where |q_r - p_r| < 1e-7 mm (no cancellation)."""
    d = q[..., 0] - p[..., 0]
    small = jnp.abs(d) < 1e-7
    safe = jnp.where(small, 1.0, d)
    diff = (
        _beyond_antiderivative(q[..., 0], radius, axisymmetric)
        - _beyond_antiderivative(p[..., 0], radius, axisymmetric)
    ) / safe
    mid = 0.5 * (p[..., 0] + q[..., 0])
    if axisymmetric:
        near = 0.5 * (mid**2 - radius**2) + d**2 / 24.0
    else:
        near = mid - radius
    near = jnp.where(mid > radius, near, 0.0)
    return jnp.where(small, near, diff) * (q[..., 1] - p[..., 1])


def polygon_measure_beyond(polygons, radius: float, axisymmetric: bool):
    """Signed measure (volume of revolution, mm^3; plane strain, mm^2) of the parts of
    the polygons (..., m, 2) at r >= ``radius`` (positive for counter-clockwise ones):
    Green's theorem, int int_{r > R} r dA = oint f(r) dz with f = (r^2 - R^2)/2 beyond R
    and 0 before it (plane: f = r - R), each straight edge's integral in closed form.
    Continuously differentiable in the vertices (f is continuous); for any closed
    polygon (the cavity of :func:`part_cavity_volume`), where :func:`measure_beyond` takes
    a mesh's quadrilaterals."""
    p = jnp.asarray(polygons)
    q = jnp.roll(p, -1, axis=-2)
    total = jnp.sum(_edge_beyond(p, q, radius, axisymmetric), axis=-1)
    return 2.0 * jnp.pi * total if axisymmetric else total


def part_cavity_volume(points, travel, radius: float, axisymmetric: bool, corner_radius=None):
    """The cavity of a closed die's profile ``points`` moved down by ``travel`` (its
    corners rounded by ``corner_radius``, sharp where None), the axis and the mid-plane
    (:func:`_cavity_polygon`), inside r <= ``radius`` (the part; the flash land beyond
    it)."""
    poly = _cavity_polygon(points, travel, corner_radius)
    poly = poly[::-1]  # counter-clockwise: axis, mid-plane, then back along the die
    whole = polygon_measure(poly, axisymmetric)
    return whole - polygon_measure_beyond(poly, radius, axisymmetric)


@dataclass(frozen=True, eq=False)
class UnfilledPart(_Identity):
    """1 - die fill of a closed die with a flash land at the end of the run: 1 - (the
    material inside r <= ``radius``) / (the top die's cavity there, its corners rounded
    as the contact and the history's ``die_fill`` see them, :func:`part_cavity_volume`).
    The material there lies under the die and above the mid-plane, so it is the part of
    the cavity it fills (0 = filled)."""

    elements: np.ndarray  # the final mesh's elements
    radius: float
    axisymmetric: bool
    unit = "-"

    def __call__(self, traj, inputs):
        quads = traj.positions[self.elements]
        axi = self.axisymmetric
        beyond = measure_beyond(traj.positions, self.elements, self.radius, axi)
        inside = jnp.sum(polygon_measure(quads, axi) - beyond)
        die = inputs.die.members[0]
        t = traj.time_s[-1]
        surface = die_surface(die.points, die.travel(t), die.corner_radius)
        inside = inside + conformed_change(traj.positions, self.elements, surface, axi, self.radius)
        cav = part_cavity_volume(die.points, die.travel(t), self.radius, axi, die.corner_radius)
        return 1.0 - inside / cav


@dataclass(frozen=True, eq=False)
class MeanTemperature(_Identity):
    """The mean temperature (K) of the part at the end of the run, each node weighted by
    a quarter of the volume of each element it belongs to (at the final positions); the
    temperature unknown counts from the run's billet temperature."""

    elements: np.ndarray  # the final mesh's elements
    layout: object  # the final mesh's jaxform.assembly.Layout
    axisymmetric: bool
    unit = "K"

    def __call__(self, traj, inputs):
        lay = self.layout
        vol = jnp.abs(polygon_measure(traj.positions[self.elements], self.axisymmetric))
        n = traj.positions.shape[0]
        w = jnp.zeros(n).at[self.elements.ravel()].add(jnp.repeat(0.25 * vol, 4))
        temps = lay.nodal(traj.x)[:, lay.temperature_column]
        return jnp.sum(w * temps) / jnp.sum(w) + inputs.thermal.billet_temperature_K
