"""Closed-form determinants and inverses of 2x2 and 3x3 matrices (batched on leading axes).

XLA lowers ``jnp.linalg.det`` / ``inv`` to batched LU factorizations, which for millions of
tiny matrices (and their forward-mode tangents) cost far more than the cofactor formulas.
These are plain polynomial expressions: differentiable everywhere, exact for det != 0.
"""

from __future__ import annotations

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


def _cofactors3(a):
    c00 = a[..., 1, 1] * a[..., 2, 2] - a[..., 1, 2] * a[..., 2, 1]
    c01 = a[..., 1, 2] * a[..., 2, 0] - a[..., 1, 0] * a[..., 2, 2]
    c02 = a[..., 1, 0] * a[..., 2, 1] - a[..., 1, 1] * a[..., 2, 0]
    c10 = a[..., 0, 2] * a[..., 2, 1] - a[..., 0, 1] * a[..., 2, 2]
    c11 = a[..., 0, 0] * a[..., 2, 2] - a[..., 0, 2] * a[..., 2, 0]
    c12 = a[..., 0, 1] * a[..., 2, 0] - a[..., 0, 0] * a[..., 2, 1]
    c20 = a[..., 0, 1] * a[..., 1, 2] - a[..., 0, 2] * a[..., 1, 1]
    c21 = a[..., 0, 2] * a[..., 1, 0] - a[..., 0, 0] * a[..., 1, 2]
    c22 = a[..., 0, 0] * a[..., 1, 1] - a[..., 0, 1] * a[..., 1, 0]
    return jnp.stack(
        [
            jnp.stack([c00, c01, c02], axis=-1),
            jnp.stack([c10, c11, c12], axis=-1),
            jnp.stack([c20, c21, c22], axis=-1),
        ],
        axis=-2,
    )


def det3(a):
    c = _cofactors3(a)
    return jnp.sum(a[..., 0, :] * c[..., 0, :], axis=-1)


def inv3(a):
    """Inverse = adjugate / det (adjugate = transposed cofactor matrix)."""
    c = _cofactors3(a)
    d = jnp.sum(a[..., 0, :] * c[..., 0, :], axis=-1)
    return jnp.swapaxes(c, -1, -2) / d[..., None, None]
