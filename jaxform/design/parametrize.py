"""Design parametrizations: small immutable maps from design variables to run inputs.

A parametrization (a *group*) owns one array of dimensionless design variables ``u``
and maps it onto the inputs of a differentiable run:

    group.apply(u, inputs, times) -> (inputs, times)      pure, traceable
    group.initial()                -> u0 (the scene as configured)
    group.bounds()                 -> (lo, hi) box bounds on u
    group.physical(u)              -> {name: value} in the config's units (for CSVs)

Groups compose left to right (:func:`apply_all`).  The design pytree is a dict
``{group.name: u}``.

* :class:`MaterialParams`  ``u_i = log(p_i / p0_i)`` of chosen parameters (positive,
  scale-free): e.g. Anand's s0, h0, s_hat for identification.
* :class:`Friction`        the friction coefficients themselves (mu or m), one per die
  whose law has one.
* :class:`RamSpeed`        ``u = log(v / v0)``: the die path table's times and the step
  schedule are divided by v/v0 (same strokes, reached sooner or later).
* :class:`PreformCosine`   the billet's lateral profile r(z) = R0 c (1 + sum_k a_k
  cos(k pi z / H)), k = 1..n, every node moved radially in proportion, with c chosen so
  that the *discrete* volume of the mesh is that of the cylinder (constant volume).
* :class:`DieProfile`      vertical offsets (mm) of chosen die profile points.
* :class:`BilletAspect`    ``u = log(H / H0)``: the billet taller and thinner at fixed
  volume (a process's first operation; its top die moved with the billet's top).
* :class:`DwellTime`       ``u = log(t / t0)``: a dwell's (furnace's) time.
* :class:`DieSpline`       the top die's profile between two radii as a clamped cubic
  B-spline of heights z(r): offsets (mm) of its control heights, sampled onto the die's
  points there; manufacturability (draft angle, fillet radius) as an exterior penalty
  (:meth:`DieSpline.penalty`) and a report of each constraint's margin
  (:mod:`jaxform.design.spline`).
* :class:`Thermal`         chosen thermal inputs of a coupled run: billet and die
  temperatures (u in 100 K from the configured ones), log of the die contact conductance,
  the Taylor-Quinney factor.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import jax
import jax.numpy as jnp
import numpy as np

from jaxform.design.spline import Manufacturability, SplineBasis
from jaxform.geometry import polygon_measure


def _revolved_areas(pos, elements, axisymmetric: bool):
    """Volume (axisymmetric, 2 pi r dA) or area of each quadrilateral (shoelace/Pappus)."""
    return polygon_measure(pos[elements], axisymmetric)


def workpiece_volume(pos, elements, axisymmetric: bool):
    """Material volume (mm^3; mm^2 per mm depth in plane strain) of a mesh at ``pos``."""
    return jnp.sum(_revolved_areas(pos, elements, axisymmetric))


@dataclass(frozen=True)
class MaterialParams:
    names: tuple[str, ...]
    p0: tuple[float, ...]
    bound_log: float = float(np.log(2.0))  # |log(p/p0)| <= this
    name: str = "material"

    def initial(self):
        return _zeros(len(self.names))

    def bounds(self):
        b = jnp.full(len(self.names), self.bound_log)
        return -b, b

    def values(self, u):
        return jnp.asarray(self.p0) * jnp.exp(u)

    def apply(self, u, inputs, times):
        v = self.values(u)
        params = replace(inputs.params, **{n: v[i] for i, n in enumerate(self.names)})
        return replace(inputs, params=params), times

    def physical(self, u):
        v = np.asarray(self.values(u))
        return {n: float(v[i]) for i, n in enumerate(self.names)}


@dataclass(frozen=True)
class FrictionCoefficient:
    """One friction design variable: the coefficient ``field`` (mu, m) of the law of die
    ``die`` (its index in the scene's dies, named ``die_name``), from ``value0`` within
    [0, ``high``]; ``key`` is the config key that sets it (friction.m, die.friction.m)."""

    die: int
    die_name: str
    field: str
    value0: float
    high: float
    key: str


@dataclass(frozen=True)
class Friction:
    """The friction coefficients themselves, one variable per die whose law has one."""

    variables: tuple[FrictionCoefficient, ...]
    name: str = "friction"

    def initial(self):
        return jnp.asarray([v.value0 for v in self.variables])

    def bounds(self):
        return jnp.zeros(len(self.variables)), jnp.asarray([v.high for v in self.variables])

    def apply(self, u, inputs, times):
        dies = list(inputs.die.members)
        for i, v in enumerate(self.variables):
            d = dies[v.die]
            dies[v.die] = replace(d, friction=replace(d.friction, **{v.field: u[i]}))
        return replace(inputs, die=inputs.die.with_members(dies)), times

    def physical(self, u):
        return {f"friction_{v.die_name}_{v.field}": float(u[i])
                for i, v in enumerate(self.variables)}  # fmt: skip


@dataclass(frozen=True)
class RamSpeed:
    speed0_mm_s: float
    bound_log: float = float(np.log(4.0))
    name: str = "speed"

    def initial(self):
        return _zeros(1)

    def bounds(self):
        return jnp.full(1, -self.bound_log), jnp.full(1, self.bound_log)

    def apply(self, u, inputs, times):
        slow = jnp.exp(-u[0])  # time scale factor v0 / v
        die = inputs.die.replace_each(lambda d: replace(d, path_time_s=d.path_time_s * slow))
        return replace(inputs, die=die), times * slow

    def physical(self, u):
        return {"speed_mm_s": float(self.speed0_mm_s * np.exp(float(u[0])))}


# the inputs the 'thermal' group may vary, in the order of its variables
THERMAL_VARIABLES = ("billet_temperature_K", "die_temperature_K", "htc_die_W_m2K", "taylor_quinney")


@dataclass(frozen=True)
class Thermal:
    """Chosen thermal inputs (``names``, of :data:`THERMAL_VARIABLES`; a process's dwell:
    air_temperature_K, htc_air_W_m2K) from their configured values ``start``: a
    temperature as u = (T - T_start) / 100 K (within +-``temperature_max_K``), a
    conductance (htc_*) as u = log(h / h_start) (within a factor exp(bound_log)), the
    Taylor-Quinney factor as itself (in [0, 1])."""

    names: tuple[str, ...]
    start: tuple[float, ...]
    bound_log: float = float(np.log(4.0))
    temperature_max_K: float = 200.0
    name: str = "thermal"

    KELVIN_PER_UNIT = 100.0

    def initial(self):
        return jnp.asarray([v if n == "taylor_quinney" else 0.0
                            for n, v in zip(self.names, self.start)])  # fmt: skip

    def bounds(self):
        t = self.temperature_max_K / self.KELVIN_PER_UNIT
        log = (-self.bound_log, self.bound_log)
        box = {"taylor_quinney": (0.0, 1.0)}
        lo, hi = zip(*(log if n.startswith("htc_") else box.get(n, (-t, t)) for n in self.names))
        return jnp.asarray(lo), jnp.asarray(hi)

    def values(self, u):
        """{name: value in the config's units} at u."""
        out = {}
        for i, (n, v0) in enumerate(zip(self.names, self.start)):
            if n.startswith("htc_"):  # a conductance: log-scaled
                out[n] = v0 * jnp.exp(u[i])
            elif n == "taylor_quinney":
                out[n] = u[i]
            else:
                out[n] = v0 + self.KELVIN_PER_UNIT * u[i]
        return out

    def apply(self, u, inputs, times):
        return replace(inputs, thermal=replace(inputs.thermal, **self.values(u))), times

    def physical(self, u):
        return {n: float(v) for n, v in self.values(u).items()}


@dataclass(frozen=True)
class PreformCosine:
    n_modes: int
    height_mm: float  # half height of the modelled section (z from 0 to H)
    radius_mm: float  # R0
    elements: np.ndarray  # (n_el, 4) for the volume
    axisymmetric: bool = True
    amplitude_max: float = 0.2
    name: str = "preform"

    def __hash__(self):  # arrays are set-up constants; identity is enough
        return id(self)

    def initial(self):
        return _zeros(self.n_modes)

    def bounds(self):
        b = jnp.full(self.n_modes, self.amplitude_max)
        return -b, b

    def profile(self, u, z):
        """Unscaled profile factor 1 + sum_k a_k cos(k pi z / H) at heights z."""
        k = jnp.arange(1, self.n_modes + 1)
        return 1.0 + jnp.sum(
            u[None, :] * jnp.cos(jnp.pi * k[None, :] * z[:, None] / self.height_mm), axis=1
        )

    def shape(self, u, coords):
        coords = jnp.asarray(coords)
        moved = coords.at[:, 0].multiply(self.profile(u, coords[:, 1]))
        if self.axisymmetric:  # every radius times c scales the volume by c^2
            v0 = workpiece_volume(coords, self.elements, True)
            c = jnp.sqrt(v0 / workpiece_volume(moved, self.elements, True))
        else:  # plane strain: the area scales by c
            c = workpiece_volume(coords, self.elements, False) / workpiece_volume(
                moved, self.elements, False
            )
        return moved.at[:, 0].multiply(c)

    def apply(self, u, inputs, times):
        return replace(inputs, coords=self.shape(u, inputs.coords)), times

    def physical(self, u):
        return {f"preform_a{k + 1}": float(u[k]) for k in range(self.n_modes)}


@dataclass(frozen=True)
class NodalCoordinates:
    """The preform as raw initial nodal coordinates: one variable (mm) per node coordinate
    that no boundary condition holds (u_r on the axis and u_z on the mid-plane stay
    put, so the section keeps its axis and symmetry plane).  The most general preform
    shape, for gradients (e.g. a sensitivity map of an objective over the initial
    surface); unlike ``PreformCosine`` it keeps neither the volume nor smoothness."""

    nodes: np.ndarray  # (k,) node of each variable
    components: np.ndarray  # (k,) its coordinate: 0 = r (x), 1 = z (y)
    offset_max_mm: float = 0.1
    name: str = "nodes"

    def __hash__(self):  # arrays are set-up constants; identity is enough
        return id(self)

    def initial(self):
        return _zeros(len(self.nodes))

    def bounds(self):
        b = jnp.full(len(self.nodes), self.offset_max_mm)
        return -b, b

    def apply(self, u, inputs, times):
        coords = jnp.asarray(inputs.coords).at[self.nodes, self.components].add(u)
        return replace(inputs, coords=coords), times

    def physical(self, u):
        return {
            f"node{n}_d{'rz'[c]}_mm": float(u[k])
            for k, (n, c) in enumerate(zip(self.nodes, self.components))
        }


@dataclass(frozen=True)
class DieProfile:
    points: tuple[int, ...]  # indices into the die profile
    offset_max_mm: float = 1.0
    name: str = "die"

    def initial(self):
        return _zeros(len(self.points))

    def bounds(self):
        b = jnp.full(len(self.points), self.offset_max_mm)
        return -b, b

    def apply(self, u, inputs, times):
        def move(d):
            return replace(d, points=d.points.at[jnp.asarray(self.points), 1].add(u))

        return replace(inputs, die=inputs.die.replace_top(move)), times

    def physical(self, u):
        return {f"die_dz{i}_mm": float(u[k]) for k, i in enumerate(self.points)}


@dataclass(frozen=True)
class BilletAspect:
    """The billet's height against its diameter at fixed volume: u = log(H / H0), every
    node's z times e^u about the mid-plane (or the bottom, z = 0), its r times e^(-u/2)
    (axisymmetric; plane strain e^(-u)), so the volume stays exactly that of the mesh;
    the top die moves with the billet's top (the mesh's highest z as the group finds it,
    so that with the volume group too it follows the product of both scalings), so it
    starts where it started and closes by the same stroke."""

    axisymmetric: bool = True
    bound_log: float = float(np.log(1.25))
    name: str = "billet"
    lifts_the_die = True  # applied after the groups that set die heights (a die spline)

    def initial(self):
        return _zeros(1)

    def bounds(self):
        return jnp.full(1, -self.bound_log), jnp.full(1, self.bound_log)

    def apply(self, u, inputs, times):
        tall = jnp.exp(u[0])
        thin = jnp.exp(-0.5 * u[0]) if self.axisymmetric else 1.0 / tall
        coords = jnp.asarray(inputs.coords) * jnp.stack([thin, tall])[None, :]
        lift = (tall - 1.0) * jnp.max(jnp.asarray(inputs.coords)[:, 1])

        def move(d):
            return replace(d, points=d.points.at[:, 1].add(lift))

        return replace(inputs, coords=coords, die=inputs.die.replace_top(move)), times

    def physical(self, u):
        tall = float(np.exp(float(u[0])))
        thin = tall ** (-0.5 if self.axisymmetric else -1.0)
        return {"billet_height_factor": tall, "billet_diameter_factor": thin}


@dataclass(frozen=True)
class BilletVolume:
    """The billet's volume at fixed aspect: u = log(V / V0), every node's r and z times
    e^(u/3) (axisymmetric; plane strain e^(u/2)) about the axis and the mid-plane (or the
    bottom, z = 0); the top die moves with the billet's top (its highest z as the group
    finds it), so it starts where it started and closes by the same stroke."""

    axisymmetric: bool = True
    bound_log: float = float(np.log(1.25))
    name: str = "billet_volume"
    lifts_the_die = True

    def initial(self):
        return _zeros(1)

    def bounds(self):
        return jnp.full(1, -self.bound_log), jnp.full(1, self.bound_log)

    def apply(self, u, inputs, times):
        grow = jnp.exp(u[0] / (3.0 if self.axisymmetric else 2.0))
        coords = jnp.asarray(inputs.coords) * grow
        lift = (grow - 1.0) * jnp.max(jnp.asarray(inputs.coords)[:, 1])

        def move(d):
            return replace(d, points=d.points.at[:, 1].add(lift))

        return replace(inputs, coords=coords, die=inputs.die.replace_top(move)), times

    def physical(self, u):
        return {"billet_volume_factor": float(np.exp(float(u[0])))}


@dataclass(frozen=True)
class DwellTime:
    """The time of a dwell (or a furnace) as u = log(t / t0): its step times and its
    (still) die's path table scaled by e^u."""

    time0_s: float
    bound_log: float = float(np.log(2.0))
    name: str = "dwell"

    def initial(self):
        return _zeros(1)

    def bounds(self):
        return jnp.full(1, -self.bound_log), jnp.full(1, self.bound_log)

    def apply(self, u, inputs, times):
        longer = jnp.exp(u[0])
        die = inputs.die.replace_each(lambda d: replace(d, path_time_s=d.path_time_s * longer))
        return replace(inputs, die=die), times * longer

    def physical(self, u):
        return {"dwell_time_s": float(self.time0_s * np.exp(float(u[0])))}


@dataclass(frozen=True, eq=False)
class DieSpline:
    """The top die's points ``points`` (indices, radii increasing in [r0, r1]) at the
    heights of a clamped cubic B-spline: control heights c = c0 + u at the controls
    ``free`` (the others, the ends where pinned, stay at c0).  ``penalty(u)`` is
    ``weight`` x the sum of squared relative violations of the slope (draft) and
    curvature (fillet) rows of :mod:`jaxform.design.spline`; 0 where they all hold."""

    spline: SplineBasis
    points: np.ndarray  # (k,) die point indices sampled by the spline
    c0: np.ndarray  # (n,) control heights of the start design (mm)
    free: np.ndarray  # (m,) the controls that are design variables
    limits: Manufacturability = Manufacturability()
    offset_max_mm: float = 1.0
    weight: float = 10.0
    name: str = "die_spline"

    def __hash__(self):  # arrays are set-up constants; identity is enough
        return id(self)

    def initial(self):
        return _zeros(len(self.free))

    def bounds(self):
        b = jnp.full(len(self.free), self.offset_max_mm)
        return -b, b

    def controls(self, u):
        """(n,) control heights (mm) of design u."""
        return jnp.asarray(self.c0).at[jnp.asarray(self.free)].add(u)

    def heights(self, u):
        """(k,) heights (mm) of the sampled die points."""
        return jnp.asarray(self.spline.heights()) @ self.controls(u)

    def apply(self, u, inputs, times):
        z = self.heights(u)

        def move(d):
            return replace(d, points=d.points.at[jnp.asarray(self.points), 1].set(z))

        return replace(inputs, die=inputs.die.replace_top(move)), times

    def violations(self, u) -> dict:
        """{constraint: relative violation of each row (>0 where violated)}: slope
        coefficients over the draft's limit (per unit limit), z'' coefficients over the
        fillet's (per unit limit); only the constraints that are set."""
        c = self.controls(u)
        out = {}
        if np.isfinite(self.limits.slope_max):
            s = self.limits.slope_max
            out["draft"] = jnp.abs(jnp.asarray(self.spline.slope()) @ c) / s - 1.0
        if np.isfinite(self.limits.curvature_max):
            k = self.limits.curvature_max
            out["fillet"] = jnp.abs(jnp.asarray(self.spline.second()) @ c) / k - 1.0
        return out

    def penalty(self, u):
        """weight x sum of max(0, violation)^2 over every constraint row."""
        total = jnp.zeros(())
        for v in self.violations(u).values():
            total = total + jnp.sum(jnp.maximum(v, 0.0) ** 2)
        return self.weight * total

    def report(self, u) -> list[dict]:
        """Each constraint's value, limit and margin (value - limit for a lower bound):
        the draft angle and fillet radius guaranteed by the coefficients (the rows the
        penalty sees), the same measured on a fine grid of the curve, and the undercut
        (0 by construction)."""
        c = np.asarray(self.controls(jnp.asarray(u)))
        lim = self.limits
        slope = float(np.max(np.abs(self.spline.slope() @ c)))
        curv = float(np.max(np.abs(self.spline.second() @ c)))
        _, _, b1, b2 = self.spline.dense()
        z1, z2 = b1 @ c, b2 @ c
        kappa = float(np.max(np.abs(z2) / (1.0 + z1**2) ** 1.5))
        rows = [
            ("draft_deg", _draft(slope), lim.draft_deg),
            ("draft_sampled_deg", _draft(float(np.max(np.abs(z1)))), lim.draft_deg),
            ("fillet_radius_mm", _radius(curv), lim.fillet_radius_min_mm),
            ("fillet_radius_sampled_mm", _radius(kappa), lim.fillet_radius_min_mm),
            ("undercut_mm", 0.0, 0.0),
        ]
        return [dict(constraint=n, value=v, limit=lo, margin=v - lo if n[0] != "u" else 0.0)
                for n, v, lo in rows]  # fmt: skip

    def physical(self, u):
        c = np.asarray(self.controls(jnp.asarray(u)))
        return {f"spline_z{j}_mm": float(c[j]) for j in range(len(c))}


def _draft(slope: float) -> float:
    """The angle (deg) of a wall of slope |dz/dr| from the press direction."""
    return float(np.degrees(np.arctan2(1.0, slope)))


def _radius(curvature: float) -> float:
    return float(1.0 / curvature) if curvature > 0.0 else float("inf")


def penalty_of(groups, design: dict):
    """The sum of the groups' constraint penalties (those that have one) at design."""
    total = 0.0
    for g in groups:
        if hasattr(g, "penalty"):
            total = total + g.penalty(design[g.name])
    return total


def constraint_report(groups, design: dict) -> list[dict]:
    """Every constraint of every group that has some: rows with group, constraint,
    value, limit, margin."""
    return [dict(group=g.name, **row) for g in groups if hasattr(g, "report")
            for row in g.report(np.asarray(design[g.name]))]  # fmt: skip


def _zeros(n: int) -> jax.Array:
    """A start design on the device without compiling a program for it (``jnp.zeros``
    compiles, or loads, one per shape)."""
    return jax.device_put(np.zeros(n))


def apply_all(groups, design: dict, inputs, times):
    """Apply every group's variables (``design[group.name]``) in order."""
    for g in groups:
        inputs, times = g.apply(design[g.name], inputs, times)
    return inputs, times


def initial_design(groups) -> dict:
    return {g.name: g.initial() for g in groups}


def design_bounds(groups) -> tuple[dict, dict]:
    lo, hi = {}, {}
    for g in groups:
        lo[g.name], hi[g.name] = g.bounds()
    return lo, hi


def physical_values(groups, design: dict) -> dict:
    out = {}
    for g in groups:
        out.update(g.physical(np.asarray(design[g.name])))
    return out
