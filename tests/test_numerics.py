"""The small numerical kernels under the element and die code, against independent
references: closed-form 3x3 / 2x2 inverses and determinants against LAPACK (NumPy),
the table interpolation against ``jnp.interp`` (values and derivatives), and the
safeguarded scalar root against roots and implicit derivatives known in closed form."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxform.implicit import root_scalar
from jaxform.smallmat import det2, det3, inv2, inv3
from jaxform.tables import interp_table


def test_small_inverses_and_determinants_match_lapack():
    """200 random well-conditioned matrices (I + 0.3 N(0, 1)): relative error <= 1e-12."""
    rng = np.random.default_rng(0)
    for n, inv, det in ((3, inv3, det3), (2, inv2, det2)):
        a = np.eye(n) + 0.3 * rng.standard_normal((200, n, n))
        got_inv, got_det = jax.jit(lambda m: (inv(m), det(m)))(jnp.asarray(a))
        np.testing.assert_allclose(got_inv, np.linalg.inv(a), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(got_det, np.linalg.det(a), rtol=1e-12)


@pytest.mark.parametrize("m", [1, 2, 5])
def test_table_interpolation_equals_jnp_interp(m):
    """Values and derivatives in t, the abscissae and the values, at random points, past
    both ends and exactly at every table point (where both take the segment to the right,
    the last segment at the last point): equal to 1e-14."""
    rng = np.random.default_rng(m)
    xs = np.concatenate([[0.0], np.cumsum(rng.uniform(0.2, 1.0, m - 1))])
    ys = rng.standard_normal(m)
    ts = np.concatenate([xs, rng.uniform(-0.5, xs[-1] + 0.5, 20), [-1.0, xs[-1] + 1.0]])

    def pieces(f):
        def at(t, x, y):
            return f(t, x, y), jax.grad(f, argnums=(0, 1, 2))(t, x, y)

        return jax.jit(jax.vmap(at, in_axes=(0, None, None)))(ts, jnp.asarray(xs), jnp.asarray(ys))

    got = pieces(interp_table)
    ref = pieces(jnp.interp)
    for a, b in zip(jax.tree_util.tree_leaves(got), jax.tree_util.tree_leaves(ref)):
        np.testing.assert_allclose(a, b, rtol=1e-14, atol=1e-14)


def test_table_with_a_zero_length_segment_jumps_like_jnp_interp():
    xs, ys = jnp.array([0.0, 1.0, 1.0, 2.0]), jnp.array([0.0, 1.0, 5.0, 6.0])
    ts = jnp.array([0.5, 1.0, 1.5, 3.0])
    f = jax.jit(jax.vmap(interp_table, in_axes=(0, None, None)))
    np.testing.assert_allclose(f(ts, xs, ys), jnp.interp(ts, xs, ys), rtol=1e-15)
    np.testing.assert_allclose(f(ts, xs, ys), [0.5, 5.0, 5.5, 6.0], rtol=1e-15)


def _cubic(x, a):
    return x**3 + x - a  # increasing in x; the root of a = 2 is x = 1


def test_scalar_root_and_its_implicit_derivative():
    """x^3 + x = a: the root (a = 2: x = 1) to 1e-14 from either end of the bracket, and
    dx/da = 1 / (3 x^2 + 1) (the implicit function theorem) to 1e-13."""

    @jax.jit
    def solve(a, x0):
        return root_scalar(_cubic, a, -10.0, 10.0, x0, 1e-15, 1e-14, 60)

    for x0 in (-10.0, 0.0, 9.0):
        x, ok = solve(2.0, x0)
        assert float(ok) == 1.0 and abs(float(x) - 1.0) <= 1e-14
    for a in (-3.0, 0.5, 7.0):
        x = float(solve(a, 0.0)[0])
        assert abs(x**3 + x - a) <= 1e-12
        d = jax.jit(jax.grad(lambda q: solve(q, 0.0)[0]))(a)
        assert abs(float(d) - 1.0 / (3.0 * x**2 + 1.0)) <= 1e-13


def test_scalar_root_iteration_cap_and_nested_root():
    """maxiter = 0 evaluates x0 alone (converged only where x0 is the root); a root inside
    another root's function: y = x(a)^2 with x^3 + x = a, dy/da = 2 x / (3 x^2 + 1)."""
    cap = jax.jit(lambda x0: root_scalar(_cubic, 2.0, -10.0, 10.0, x0, 1e-15, 1e-14, 0))
    x, ok = cap(0.0)
    assert float(x) == 0.0 and float(ok) == 0.0
    x, ok = cap(1.0)
    assert float(x) == 1.0 and float(ok) == 1.0

    def outer(y, a):  # increasing in y; root y = x(a)^2
        inner = root_scalar(_cubic, a, -10.0, 10.0, 0.0, 1e-15, 1e-14, 60)[0]
        return y - inner**2

    def y_of(a):
        return root_scalar(outer, a, -1.0, 100.0, 0.0, 1e-15, 1e-14, 60)[0]

    a = 3.0
    y, dy = jax.jit(jax.value_and_grad(y_of))(a)
    x = np.sqrt(float(y))
    assert abs(x**3 + x - a) <= 1e-12
    assert abs(float(dy) - 2.0 * x / (3.0 * x**2 + 1.0)) <= 1e-12
