"""Material-point driver: homogeneous uniaxial compression (or tension) of one point.

The point is a cylinder compressed along z with a traction-free side: the deformation
gradient is F = diag(lam_r, lam_r, lam_z) with lam_z prescribed and lam_r found in every
step by a Newton solve of T_rr(lam_r) = 0 whose Jacobian is the consistent tangent
(jax.jacfwd of the material update).  Two loadings:

* constant true strain rate ``strain_rate_1_s``: lam_z = exp(-rate * t);
* constant ram speed ``ram_speed_mm_s`` on a specimen of height ``height_mm``:
  lam_z = (H - v t) / H (the nominal strain rate v/H falls behind the true one).

Everything is a pure function; `uniaxial_compression` is jit-compiled once per law and
number of steps and can be vmapped over rates or parameters.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from jaxform.damage import N_CRITERIA
from jaxform.damage import increment as damage_increment
from jaxform.kinematics import step_kinematics
from jaxform.materials.base import MaterialState

NEWTON_ITERS = 30
NEWTON_RTOL = 1e-12


@dataclass(frozen=True)
class UniaxialResult:
    """Per-step history (index 0 = initial state). Compression counted positive."""

    time_s: np.ndarray
    strain: np.ndarray  # true (log) axial strain ln(H/h)
    stress_MPa: np.ndarray  # -T_zz
    s_MPa: np.ndarray
    eqps: np.ndarray
    newton_iterations: np.ndarray
    ok: np.ndarray
    lateral_stretch: np.ndarray  # current radius / initial radius
    damage: np.ndarray  # (n+1, 3) damage integrals (jaxform.damage.CRITERIA)


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class Ram:
    """Compression by a ram at a constant speed (mm/s) on a specimen of height_mm (mm):
    the strain rate grows as the height falls (the thesis' upsetting)."""

    speed_mm_s: float | jax.Array
    height_mm: float | jax.Array


def _axial_stretch(t, rate, speed_mm_s, height_mm):
    """lam_z(t): exp(-rate t) for a true strain rate, or 1 - v t / H for a ram speed."""
    by_rate = jnp.exp(-rate * t)
    by_speed = 1.0 - speed_mm_s * t / height_mm
    return jnp.where(speed_mm_s > 0.0, by_speed, by_rate)


def _lateral_solve(law, params, state, dt, fz, alpha):
    """Find the lateral stretch ratio (as x = log f_rr) with T_rr = 0; returns x, iters, ok."""

    def trr(x):
        f = jnp.diag(jnp.stack([jnp.exp(x), jnp.exp(x), fz]))
        stress, _, ok = law.update(step_kinematics(f, alpha), state, params, dt)
        return stress[0, 0], ok

    scale = jnp.maximum(jnp.abs(params.G_MPa * jnp.log(fz)), 1e-30)

    def cond(c):
        x, r, it, done = c
        return (~done) & (it < NEWTON_ITERS)

    def body(c):
        x, _, it, _ = c
        (r, ok), (dr, _) = jax.jvp(trr, (x,), (jnp.ones_like(x),))
        x_new = x - r / dr
        done = jnp.abs(r) <= NEWTON_RTOL * scale
        x_new = jnp.where(done, x, x_new)
        return x_new, r, it + 1, done | ~ok

    x0 = -0.5 * jnp.log(fz)
    x, r, it, _ = jax.lax.while_loop(cond, body, (x0, jnp.inf, 0, False))
    r_final, ok = trr(x)
    ok = ok & (jnp.abs(r_final) <= 1e3 * NEWTON_RTOL * scale)
    return x, it, ok


def uniaxial_compression(
    law,
    params,
    *,
    final_strain: float,
    n_steps: int,
    strain_rate_1_s: float | jax.Array = 0.0,
    ram: Ram | None = None,
    alpha: float = 0.5,
    times_s: jax.Array | None = None,
) -> dict:
    """Run the compression in n_steps equal time steps up to true strain final_strain.

    Give either ``strain_rate_1_s`` (> 0, constant) or ``ram`` (:class:`Ram`).
    ``times_s`` (increasing, without 0) replaces the equal steps by these step end times
    (then final_strain and n_steps are ignored).
    Returns a dict of arrays (see UniaxialResult); jit- and vmap-friendly.
    """
    rate = jnp.asarray(strain_rate_1_s, dtype=jnp.float64)
    speed = jnp.asarray(0.0 if ram is None else ram.speed_mm_s, dtype=jnp.float64)
    height = jnp.asarray(1.0 if ram is None else ram.height_mm, dtype=jnp.float64)
    # total time to reach the final true strain
    t_end_rate = final_strain / jnp.where(rate > 0, rate, 1.0)
    t_end_speed = height * (1.0 - jnp.exp(-final_strain)) / jnp.where(speed > 0, speed, 1.0)
    t_end = jnp.where(speed > 0.0, t_end_speed, t_end_rate)
    if times_s is None:
        times_s = t_end / n_steps * jnp.arange(1, n_steps + 1)
    times_s = jnp.asarray(times_s, dtype=jnp.float64)
    t_prev = jnp.concatenate([jnp.zeros(1), times_s[:-1]])
    state0 = law.initial_state(params)

    def step(carry, tt):
        state, lam_z, lam_r, dmg = carry
        t_new, t_old = tt
        dt = t_new - t_old
        lam_z_new = _axial_stretch(t_new, rate, speed, height)
        fz = lam_z_new / lam_z
        x, iters, ok = _lateral_solve(law, params, state, dt, fz, alpha)
        f = jnp.diag(jnp.stack([jnp.exp(x), jnp.exp(x), fz]))
        _, new, ok_m = law.update(step_kinematics(f, alpha), state, params, dt)
        lam_r_new = lam_r * jnp.exp(x)
        dmg = dmg + damage_increment(new.stress, new.eqps - state.eqps)
        out = (
            t_new,
            -jnp.log(lam_z_new),
            -new.stress[2, 2],
            new.s,
            new.eqps,
            iters,
            ok & ok_m,
            lam_r_new,
            dmg,
        )
        return (new, lam_z_new, lam_r_new, dmg), out

    one = jnp.asarray(1.0)
    dmg0 = jnp.zeros(N_CRITERIA)
    _, outs = jax.lax.scan(step, (state0, one, one, dmg0), (times_s, t_prev))
    t, eps, sig, s, ep, it, ok, lam_r, dmg = outs

    def prepend(x, v):
        return jnp.concatenate([jnp.asarray([v], dtype=x.dtype), x])

    return dict(
        time_s=prepend(t, 0.0),
        strain=prepend(eps, 0.0),
        stress_MPa=prepend(sig, 0.0),
        s_MPa=prepend(s, state0.s),
        eqps=prepend(ep, 0.0),
        newton_iterations=prepend(it, 0),
        ok=prepend(ok, True),
        lateral_stretch=prepend(lam_r, 1.0),
        damage=jnp.concatenate([dmg0[None], dmg]),
    )


def to_result(d: dict) -> UniaxialResult:
    return UniaxialResult(**{k: np.asarray(v) for k, v in d.items()})


__all__ = ["MaterialState", "Ram", "UniaxialResult", "uniaxial_compression", "to_result"]
