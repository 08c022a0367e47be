"""polygon_measure against closed forms: areas and volumes of revolution (Pappus)."""

import jax
import jax.numpy as jnp
import numpy as np

from jaxform.geometry import polygon_measure


def test_areas_and_volumes_of_revolution_in_closed_form():
    """Square [1, 2] x [0, 1]: area 1, volume of revolution pi (2^2 - 1^2) = 3 pi; triangle
    (0,0) (1,0) (0,1): area 1/2, cone of radius 1 and height 1: pi / 3; clockwise order
    flips the sign; a batch (2, 4, 2) gives both.  Tolerance 1e-14 (round-off)."""
    square = np.array([[1.0, 0.0], [2.0, 0.0], [2.0, 1.0], [1.0, 1.0]])
    tri = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    cases = [(square, 1.0, 3.0 * np.pi), (tri, 0.5, np.pi / 3.0)]
    for poly, area, volume in cases:
        assert abs(polygon_measure(poly, False) - area) <= 1e-14
        assert abs(polygon_measure(poly, True) - volume) <= 1e-14
        assert abs(polygon_measure(poly[::-1], True) + volume) <= 1e-14
    batch = np.stack([square, square + [1.0, 0.0]])
    np.testing.assert_allclose(polygon_measure(batch, True), [3.0 * np.pi, 5.0 * np.pi], rtol=1e-14)


def test_jax_arrays_trace_and_differentiate():
    """The same function under jit equals NumPy's value (1e-14), and its gradient in a
    corner coordinate equals central differences of the volume of revolution (1e-9)."""
    square = jnp.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    f = jax.jit(lambda p: polygon_measure(p, True))
    assert abs(float(f(square)) - float(polygon_measure(np.asarray(square), True))) <= 1e-14
    g = np.asarray(jax.grad(lambda p: polygon_measure(p, True))(square))
    h = 1e-6
    e = np.zeros((4, 2))
    e[2, 0] = h
    fd = (float(f(square + e)) - float(f(square - e))) / (2 * h)
    assert abs(g[2, 0] - fd) <= 1e-9
