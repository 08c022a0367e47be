"""Piecewise-linear tables of time: die paths, die temperature changes.

:func:`interp_table` is ``jnp.interp`` for the short, increasing tables of a scene, written
as a sum over the table's segments: about a dozen operations, where ``jnp.interp``'s
binary search traces, differentiates and compiles to about a hundred per call (and the die
travel is read for every contact node of every residual).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np


def interp_table(t, xs, ys):
    """The table (xs, ys) interpolated linearly at t, constant past its ends.

    Arguments:
        t: the abscissa (a scalar, or an array: the table is read at each entry).
        xs: (m,) nondecreasing abscissae, m >= 1.
        ys: (m,) values.

    Returns:
        ys[0] plus, for each segment, its whole rise once t has passed its end and its
        slope times the part passed while t is inside it.  Values and derivatives equal
        ``jnp.interp``'s, at the table's points too: there the segment to the right of t
        counts (the last segment's, at the last point); a segment of zero length is a
        jump, taken once t reaches it.
    """
    xs, ys = jnp.asarray(xs), jnp.asarray(ys)
    t = jnp.asarray(t)[..., None]
    lo, hi = xs[:-1], xs[1:]
    dy = ys[1:] - ys[:-1]
    dx = hi - lo
    not_last = np.arange(dx.shape[0]) < dx.shape[0] - 1
    full = (t > hi) | ((t == hi) & not_last) | ((dx <= 0) & (t >= hi))
    inside = (t - lo) * (dy / jnp.where(dx > 0, dx, 1.0))
    rise = jnp.where(full, dy, jnp.where(t >= lo, inside, 0.0))
    return ys[0] + jnp.sum(rise, axis=-1)
