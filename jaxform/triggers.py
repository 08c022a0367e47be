"""What pauses a compiled chunk for the host to remesh (:mod:`jaxform.remesh`), measured
inside the chunk after each converged step (traceable):

* :func:`corner_depth_ratio`: how deep a convex die corner reaches into a free-surface
  facet, over the facet's length (the die's rounded corners against the facets as the
  boundary walks them, :meth:`jaxform.dies.RigidDie.facet_gap`);
* :func:`fold_angle_deg`: the narrowest air-side angle between the two free-surface
  facets at an open contact candidate (180 deg on a straight surface, 270 at a square
  corner of the section, 0 where the surface has folded flat onto itself).

The worst corner quality (:func:`jaxform.rezone.min_quality`), the step count and the
stroke are the other triggers (:func:`jaxform.stepping.run_chunk`).  The fold angle here
sees the candidates only; the history's ``fold_angle_deg`` (:func:`jaxform.postprocess.
fold_angle`) also sees pockets closing on the die.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxform.assembly import Indices

# the trigger bits of a paused step (outputs' ``pause_cause``)
QUALITY, STEPS, STROKE, CORNER, FOLD = 1, 2, 4, 8, 16
CAUSE_NAMES = {QUALITY: "quality", STEPS: "steps", STROKE: "stroke", CORNER: "die corner",
               FOLD: "fold"}  # fmt: skip


def causes(bits: int) -> str:
    """The names of the triggers set in ``bits`` (e.g. 'quality+fold')."""
    return "+".join(name for bit, name in CAUSE_NAMES.items() if bits & bit) or "none"


def corner_depth_ratio(die, pos, idx: Indices, t):
    """The largest depth (mm) by which a convex arc of ``die`` (of any die of a set) at
    time t reaches into a free-surface facet, over that facet's length (0 where none
    reaches in)."""
    f = idx.contact_facets
    if f.shape[0] == 0 or all(d.points.shape[0] < 3 for d in die.members):  # no arc
        return jnp.zeros((), pos.dtype)
    p = pos[idx.contact_nodes]
    xa, xb = p[f[:, 0]], p[f[:, 1]]
    g, engaged = jax.vmap(lambda a, b: die.facet_gap(a, b, t))(xa, xb)
    length = jnp.sqrt(jnp.sum((xb - xa) ** 2, axis=1))
    depth = jnp.where(engaged & (g < 0.0), -g / jnp.maximum(length, 1e-300), 0.0)
    return jnp.max(depth)


def fold_angle_deg(pos, idx: Indices, status):
    """The smallest air-side angle (deg) between the facet into and the facet out of an
    open contact candidate (status 0) that has both; 180 where none has."""
    f = idx.contact_facets
    n_c = idx.contact_nodes.shape[0]
    if f.shape[0] == 0:
        return jnp.asarray(180.0, pos.dtype)
    prev = jnp.full(n_c, -1, f.dtype).at[f[:, 1]].set(f[:, 0])
    nxt = jnp.full(n_c, -1, f.dtype).at[f[:, 0]].set(f[:, 1])
    ok = (prev >= 0) & (nxt >= 0) & (status == 0)
    p = pos[idx.contact_nodes]
    e_in = p - p[jnp.maximum(prev, 0)]
    e_out = p[jnp.maximum(nxt, 0)] - p
    cross = e_in[:, 0] * e_out[:, 1] - e_in[:, 1] * e_out[:, 0]
    turn = jnp.arctan2(cross, jnp.sum(e_in * e_out, axis=1))
    angle = jnp.where(ok, jnp.degrees(jnp.pi + turn), 180.0)
    return jnp.min(angle)
