"""Die wear by Archard's law, integrated over a run at fixed stations on each die surface.

The wear depth at a point of a die surface grows at the rate

    dw/dt = K p |v_slip|^b / H^c

with p the contact pressure (MPa), v_slip the speed at which the workpiece slides over
the die there (mm/s), H the die's hardness (MPa; optionally linear in the die temperature,
:meth:`WearInputs.hardness`) and K, b, c the law's constants (K in
mm^(1-b) s^(b-1) MPa^(c-1): dimensionless for Archard's b = c = 1, the wear depth per mm
slid per unit of p / H).

The die surface is sampled at stations fixed to the die (:func:`die_stations`: points of
its rounded profile at t = 0, equally spaced in arc length; the die carries them along its
path).  After each converged step the workpiece's contact surface gives, at every node
that faces the die, the pressure p_i (multiplier over tributary area, as
:func:`jaxform.postprocess.contact_profile` reads it) and the step's slip s_i (mm), so the
step's wear at the node is q_i = K p_i |s_i|^b dt^(1-b) / H^c (backward Euler: the end of
step's pressure and the step's mean slip speed).  A station takes the value of q
interpolated linearly along the contact facet nearest to it (both ends touching the die
and facing it, the station within a quarter of the facet's length of it); a station that
no contact facet covers gains nothing in the step.  Pure JAX, part of the compiled step
(:mod:`jaxform.stepping`), differentiable in the pressure, slip and positions (the
facet a station reads from is piecewise constant).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class WearInputs:
    """Archard's law and the stations of each die (inputs of the compiled step)."""

    stations: jax.Array  # (n_dies, n_stations, 2) points of each die surface at t = 0 (mm)
    k: jax.Array  # wear coefficient K (see the module docstring for its unit)
    hardness_MPa: jax.Array  # (n_dies,) hardness H of each die (MPa)
    b: jax.Array  # exponent of the slip speed (-)
    c: jax.Array  # exponent of the hardness (-)
    # H(T) = hardness_MPa + slope (T - reference_K) at the die temperature T (K), at least
    # 1 MPa; die_temperature_K: T of a run without a temperature field
    slope_MPa_K: jax.Array = 0.0
    reference_K: jax.Array = 293.0
    die_temperature_K: jax.Array = 293.0

    def hardness(self, temperature_K):
        """Each die's hardness (MPa) at the die temperature ``temperature_K`` (K)."""
        h = self.hardness_MPa + self.slope_MPa_K * (temperature_K - self.reference_K)
        return jnp.maximum(h, 1.0)


def die_stations(points, corner_radius: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(stations (n, 2) mm, arc length s (n,) mm from the profile's first point): n
    points equally spaced along the die's rounded profile at t = 0 (NumPy, set-up)."""
    from jaxform.dies import sample_rounded

    poly = sample_rounded(np.asarray(points, float), float(corner_radius), per_arc=32)
    seg = np.linalg.norm(np.diff(poly, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    keep = np.concatenate([[True], seg > 0.0])
    poly, s = poly[keep], s[keep]
    at = np.linspace(0.0, s[-1], n)
    return np.column_stack([np.interp(at, s, poly[:, 0]), np.interp(at, s, poly[:, 1])]), at


def _safe_power(v, e):
    pos = v > 0.0
    return jnp.where(pos, jnp.where(pos, v, 1.0) ** e, 0.0)


def node_wear(law: WearInputs, pressure, slip, dt):
    """K p |s|^b dt^(1 - b) of each contact node (before dividing by H^c): the step's
    wear there (mm times H^c)."""
    return (
        law.k * jnp.maximum(pressure, 0.0) * _safe_power(jnp.abs(slip), law.b) * dt ** (1.0 - law.b)
    )


def _at_stations(stations, pa, pb, ok, qa, qb):
    """The value interpolated along the nearest eligible facet at each station (0 where
    none covers it): stations (n_s, 2), facet ends pa, pb (n_f, 2), eligibility ok (n_f,),
    end values qa, qb (n_f,)."""
    e = pb - pa
    l2 = jnp.sum(e * e, axis=1)
    safe_l2 = jnp.where(l2 > 0.0, l2, 1.0)
    rel = stations[:, None, :] - pa[None, :, :]  # (n_s, n_f, 2)
    xi = jnp.sum(rel * e[None], axis=2) / safe_l2[None]
    xi_c = jnp.clip(xi, 0.0, 1.0)
    d = rel - xi_c[..., None] * e[None]
    dist = jnp.sqrt(jnp.sum(d * d, axis=2) + 1e-30)
    tol = 0.25 * jnp.sqrt(l2) + 1e-9
    eligible = ok[None] & (l2 > 0.0)[None] & (xi >= -1e-9) & (xi <= 1.0 + 1e-9)
    eligible = eligible & (dist <= tol[None])
    score = jnp.where(eligible, dist, jnp.inf)
    j = jnp.argmin(score, axis=1)
    found = jnp.isfinite(jnp.min(score, axis=1))
    x = jnp.take_along_axis(xi_c, j[:, None], axis=1)[:, 0]
    val = (1.0 - x) * qa[j] + x * qb[j]
    return jnp.where(found, val, 0.0)


def station_wear(law: WearInputs, pos, offsets, which, facets, counted, q, hardness):
    """The step's wear depth at every station (n_dies, n_stations) mm.

    Arguments:
        law: the stations and constants.
        pos: (n_c, 2) contact candidates' positions at the end of the step (mm).
        offsets: (n_dies, 2) each die's displacement from t = 0 at the end of the step.
        which: (n_c,) the die each candidate faces.
        facets: (n_f, 2) contact facets (candidate indices); counted: (n_f,) both ends
            touching.
        q: (n_c,) :func:`node_wear` of each candidate.
        hardness: (n_dies,) each die's hardness H (MPa; :meth:`WearInputs.hardness`).
    """
    a, b = facets[:, 0], facets[:, 1]
    rows = []
    for d in range(law.stations.shape[0]):  # a few dies: unrolled
        ok = (counted > 0) & (which[a] == d) & (which[b] == d)
        w = _at_stations(law.stations[d], pos[a] - offsets[d], pos[b] - offsets[d], ok,
                         q[a], q[b])  # fmt: skip
        rows.append(w / hardness[d] ** law.c)
    return jnp.stack(rows)
