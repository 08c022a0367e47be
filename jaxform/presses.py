"""Presses and hammers: how the ram moves, as small immutable strategy objects.

Each press is a frozen dataclass registered as a PyTree: its kind and counts are static,
its numbers are leaves (so a gradient can be taken with respect to them).  The scene
(:mod:`jaxform.scenes`) resolves the config's ``[press]`` section into one of them; no
config or kind string goes further down.  Units: mm, s, N (energies in N mm = mJ).

* :class:`SpeedPress`: the ram follows the die's path table (constant speed is a
  two-row table): today's motion, the default.
* :class:`CrankPress`: a mechanical crank press.  Slider-crank kinematics, exact closed
  form: with crank radius r = stroke / 2, connecting rod l and crank angle theta
  (0 at top dead centre), the ram is s(theta) = r (1 - cos theta) + l -
  sqrt(l^2 - r^2 sin^2 theta) below top dead centre; theta = theta0 + omega t,
  omega = 2 pi strokes_per_min / 60.  The run ends at bottom dead centre (theta = pi).
  The die's motion is :class:`CrankMotion` (read by :meth:`jaxform.dies.RigidDie.travel`).
* :class:`EnergyPress`: a screw press (one stroke) or a hammer (``blows`` blows), whose
  ram stops when its energy is spent.  The finite-element steps stay quasi-static (no
  inertia in the workpiece); the ram decelerates with the work it does: a blow of energy
  E (the ram's kinetic energy at impact, J x 1000 = N mm) delivers efficiency x E as work
  on the part, W = integral of force d(stroke), and the ram's speed follows the energy
  left, v = v0 sqrt(1 - W / (efficiency E)) (v0: the impact speed), which sets the time of
  each step and so the viscoplastic strain rate.  The stepping is :mod:`jaxform.blows`.
* Every press has a capacity ``capacity_N`` (0: none): a run whose ram force reaches it
  stops there, as a real press stalls.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np

J_TO_NMM = 1000.0  # 1 J = 1000 N mm


def slider_crank(theta, r, rod, xp=jnp):
    """Ram position below top dead centre (mm) at crank angle theta (rad), crank radius r,
    connecting rod ``rod`` (mm): r (1 - cos theta) + rod - sqrt(rod^2 - r^2 sin^2 theta)."""
    return r * (1.0 - xp.cos(theta)) + rod - xp.sqrt(rod**2 - (r * xp.sin(theta)) ** 2)


def slider_crank_speed(theta, r, rod, omega, xp=jnp):
    """d s / d t (mm/s) of :func:`slider_crank` at crank angle theta turning at omega."""
    sin, cos = xp.sin(theta), xp.cos(theta)
    return omega * r * sin * (1.0 + r * cos / xp.sqrt(rod**2 - (r * sin) ** 2))


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class CrankMotion:
    """A die driven by a slider crank: travel(t) = share x (s(theta(t)) - s(theta0)),
    theta(t) = theta0 + omega (t - delay), held before ``delay_s`` and after bottom dead
    centre.  ``share``: the part of the ram travel this die makes (a half-height model's
    top die: 1/2)."""

    radius_mm: jax.Array
    rod_mm: jax.Array
    omega_rad_s: jax.Array
    theta0_rad: jax.Array
    share: jax.Array
    delay_s: jax.Array

    def _theta(self, t, xp):
        span = (np.pi - self.theta0_rad) / self.omega_rad_s
        tau = xp.clip(t - self.delay_s, 0.0, span)
        return self.theta0_rad + self.omega_rad_s * tau

    def travel(self, t):
        """Downward travel of the die (mm) at time t (traced)."""
        s = slider_crank(self._theta(t, jnp), self.radius_mm, self.rod_mm)
        return self.share * (s - slider_crank(self.theta0_rad, self.radius_mm, self.rod_mm))

    def travel_at(self, t) -> float:
        """:meth:`travel` on the host (NumPy)."""
        r, rod = float(self.radius_mm), float(self.rod_mm)
        th0 = float(self.theta0_rad)
        th = float(self._theta(np.asarray(float(t)), np))
        return float(self.share) * float(
            slider_crank(th, r, rod, np) - slider_crank(th0, r, rod, np)
        )

    @property
    def end_s(self) -> float:
        """The time of bottom dead centre (s)."""
        return float(self.delay_s) + float((np.pi - self.theta0_rad) / self.omega_rad_s)


def crank_start_angle(stroke_mm: float, rod_mm: float, travel_mm: float) -> float:
    """The crank angle theta0 (rad, in [0, pi]) from which the ram travels ``travel_mm``
    to bottom dead centre: s(pi) - s(theta0) = travel (s increases on [0, pi]), by
    bisection to machine precision."""
    r = 0.5 * stroke_mm
    target = slider_crank(np.pi, r, rod_mm, np) - travel_mm
    lo, hi = 0.0, np.pi
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if slider_crank(mid, r, rod_mm, np) < target:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class SpeedPress:
    """The ram follows the die path table (or constant speed); ``capacity_N``: the force
    at which the press stalls (0: none)."""

    capacity_N: float = field(default=0.0, metadata=dict(static=True))
    name: str = field(default="speed", metadata=dict(static=True))
    energy_limited = False


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class CrankPress:
    """A mechanical crank press (:func:`slider_crank`): its motion is ``motion``."""

    motion: CrankMotion
    stroke_mm: float = field(metadata=dict(static=True))
    strokes_per_min: float = field(metadata=dict(static=True))
    capacity_N: float = field(default=0.0, metadata=dict(static=True))
    name: str = field(default="crank", metadata=dict(static=True))
    energy_limited = False


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class EnergyPress:
    """A screw press (``blows`` = 1) or a hammer: each blow delivers ``efficiency`` x
    ``energy_Nmm`` as work on the part; the ram hits at ``impact_speed_mm_s`` and slows
    with the work done.  ``steps_per_blow``: the load steps of each blow (the step size's
    role: each absorbs an equal share of the energy left)."""

    energy_Nmm: jax.Array
    efficiency: jax.Array
    impact_speed_mm_s: jax.Array
    blows: int = field(metadata=dict(static=True))
    steps_per_blow: int = field(metadata=dict(static=True))
    capacity_N: float = field(default=0.0, metadata=dict(static=True))
    name: str = field(default="hammer", metadata=dict(static=True))
    energy_limited = True

    @property
    def work_per_blow_Nmm(self):
        """The work each blow does on the part (N mm): efficiency x energy."""
        return self.efficiency * self.energy_Nmm

    def speed(self, energy_left):
        """Ram speed (mm/s) with ``energy_left`` of the blow's work still to do:
        v0 sqrt(energy_left / (efficiency x energy))."""
        frac = jnp.maximum(energy_left / self.work_per_blow_Nmm, 0.0)
        return self.impact_speed_mm_s * jnp.sqrt(frac)

    def nominal_duration_s(self, travel_mm: float) -> float:
        """A blow's duration if it decelerated uniformly over ``travel_mm`` (for the
        scene's nominal end time; the run's end comes from the energy)."""
        return self.blows * 2.0 * travel_mm / float(self.impact_speed_mm_s)


def capacity_message(capacity_N: float, stroke_mm: float, step: int) -> str:
    """The line a run stopped by the press capacity ends with."""
    return f"press capacity {capacity_N:g} N reached at stroke {stroke_mm:.4g} mm, step {step}"


def first_over_capacity(force_N, capacity_N: float) -> int | None:
    """The first row whose force reaches the capacity (None: none does, or no capacity)."""
    if capacity_N <= 0.0 or not math.isfinite(capacity_N):
        return None
    over = np.flatnonzero(np.asarray(force_N) >= capacity_N)
    return None if over.size == 0 else int(over[0])
