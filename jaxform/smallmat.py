"""Closed-form determinants and inverses of 2x2 and 3x3 matrices (batched on leading axes).

XLA lowers ``jnp.linalg.det`` / ``inv`` to batched LU factorizations, which for millions of
tiny matrices (and their forward-mode tangents) cost far more than the cofactor formulas.
These are plain polynomial expressions: differentiable everywhere, exact for det != 0.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def det2(a):
    return a[..., 0, 0] * a[..., 1, 1] - a[..., 0, 1] * a[..., 1, 0]


def inv2(a):
    d = det2(a)
    adj = jnp.stack(
        [
            jnp.stack([a[..., 1, 1], -a[..., 0, 1]], axis=-1),
            jnp.stack([-a[..., 1, 0], a[..., 0, 0]], axis=-1),
        ],
        axis=-2,
    )
    return adj / d[..., None, None]


def _roll(a, shift: int, axis: int):
    """``jnp.roll`` by a static shift on a length-3 axis: two slices and a concatenation
    (jnp.roll lowers to more operations)."""
    head = jax.lax.slice_in_dim(a, shift, 3, axis=axis)
    tail = jax.lax.slice_in_dim(a, 0, shift, axis=axis)
    return jnp.concatenate([head, tail], axis=axis)


def _cofactors3(a):
    """C_ij = a[i+1, j+1] a[i+2, j+2] - a[i+1, j+2] a[i+2, j+1] (indices mod 3), from four
    rolled copies of ``a``: about 20 operations to trace, differentiate and compile where
    nine scalar products written out are about 110 (the same arithmetic, bit for bit)."""
    r1, r2 = _roll(a, 1, -2), _roll(a, 2, -2)  # rows i+1, i+2
    return _roll(r1, 1, -1) * _roll(r2, 2, -1) - _roll(r1, 2, -1) * _roll(r2, 1, -1)


def det3(a):
    c = _cofactors3(a)
    return jnp.sum(a[..., 0, :] * c[..., 0, :], axis=-1)


def inv3(a):
    """Inverse = adjugate / det (adjugate = transposed cofactor matrix)."""
    c = _cofactors3(a)
    d = jnp.sum(a[..., 0, :] * c[..., 0, :], axis=-1)
    return jnp.swapaxes(c, -1, -2) / d[..., None, None]
