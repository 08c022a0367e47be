"""Linear backends (jaxform.linear): selection by name, size and platform, and solves.

No GPU here: the platform is passed in, so the choice a GPU process would make is tested
on CPU; the chosen backend then solves a small non-symmetric sparse system on CPU
(jax-sparse through its CPU lowering, SciPy's spsolve), inside jit and under vmap.
"""

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxform.linear import (
    DENSE_LIMIT,
    GPU_DENSE_LIMIT,
    KLU,
    DenseLU,
    JaxSparse,
    LinearBackendWarning,
    _warn_once,
    choose_backend,
)

# (name, unknowns, platform) -> backend chosen, whether a fallback message is given
CASES = [
    ("auto", DENSE_LIMIT - 1, "cpu", "dense", False),
    ("auto", DENSE_LIMIT, "cpu", "sparse", False),
    ("sparse", 10, "cpu", "sparse", False),
    ("dense", 10**5, "cpu", "dense", False),
    ("jax-sparse", 10, "cpu", "jax-sparse", False),
    ("auto", GPU_DENSE_LIMIT - 1, "cuda", "dense", False),
    ("auto", GPU_DENSE_LIMIT, "cuda", "jax-sparse", False),
    ("sparse", 500, "cuda", "jax-sparse", True),  # klujax is CPU-only: never silently
    ("jax-sparse", 500, "cuda", "jax-sparse", False),
    ("dense", 10**5, "cuda", "dense", False),
    ("sparse", 500, "rocm", "dense", True),  # spsolve does not lower on ROCm
    ("jax-sparse", 500, "tpu", "dense", True),
    ("auto", GPU_DENSE_LIMIT, "rocm", "dense", True),
    ("auto", 500, "tpu", "dense", False),
]


@pytest.mark.parametrize("name,n,platform,expected,warns", CASES)
def test_backend_selection_by_size_and_platform(name, n, platform, expected, warns):
    _warn_once.cache_clear()  # the message is once per process
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        solver = choose_backend(name, n, platform=platform)
    assert solver.backend == expected
    assert type(solver) is {"dense": DenseLU, "sparse": KLU, "jax-sparse": JaxSparse}[expected]
    msgs = [str(w.message) for w in caught if issubclass(w.category, LinearBackendWarning)]
    assert bool(msgs) == warns, msgs
    if warns:  # the message names the setting, the platform and the backend chosen
        assert f"'{name}'" in msgs[0] and platform in msgs[0] and expected in msgs[0]


def test_fallback_message_is_given_once():
    _warn_once.cache_clear()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for _ in range(3):
            choose_backend("sparse", 500, platform="cuda")
    assert sum(issubclass(w.category, LinearBackendWarning) for w in caught) == 1


def test_unknown_backend_names_the_field_and_the_choices():
    with pytest.raises(ValueError, match="solver.linear.*auto, dense, sparse, jax-sparse"):
        choose_backend("umfpack", 10, platform="cpu")


def _system(n=40, seed=0):
    """A non-symmetric sparse matrix (tridiagonal plus a few far entries), row-major pattern."""
    rng = np.random.default_rng(seed)
    a = (
        np.diag(4.0 + rng.random(n))
        + np.diag(rng.random(n - 1) - 0.5, 1)
        + np.diag(rng.random(n - 1) - 0.5, -1)
    )
    a[0, n - 1], a[n - 3, 2], a[5, 30] = 0.7, -0.4, 1.1
    rows, cols = np.nonzero(a)  # row-major order, as the assembly builds it
    return a, jnp.asarray(rows, jnp.int32), jnp.asarray(cols, jnp.int32), rng


@pytest.mark.parametrize("name", ["dense", "sparse", "jax-sparse"])
def test_chosen_backend_solves_and_transposes_in_jit_and_vmap(name):
    a, rows, cols, rng = _system()
    n = a.shape[0]
    solver = choose_backend(name, n, platform="cpu")
    assert solver.backend == name
    vals = jnp.asarray(a[np.asarray(rows), np.asarray(cols)])
    b = jnp.asarray(rng.standard_normal(n))
    x = jax.jit(lambda v, b: solver.solve(rows, cols, v, b, n))(vals, b)
    y = jax.jit(lambda v, b: solver.solve_transpose(rows, cols, v, b, n))(vals, b)
    assert np.max(np.abs(a @ np.asarray(x) - np.asarray(b))) <= 1e-12
    assert np.max(np.abs(a.T @ np.asarray(y) - np.asarray(b))) <= 1e-12
    # a batch of matrices (the diagonal scaled) and right-hand sides, as vmap over designs
    scale = jnp.asarray([1.0, 2.0, 0.5])
    diag = jnp.asarray(np.asarray(rows) == np.asarray(cols))
    vb = jnp.where(diag[None, :], vals[None, :] * scale[:, None], vals[None, :])
    bb = jnp.asarray(rng.standard_normal((3, n)))
    xb = jax.jit(jax.vmap(lambda v, b: solver.solve(rows, cols, v, b, n)))(vb, bb)
    yb = jax.jit(jax.vmap(lambda v, b: solver.solve_transpose(rows, cols, v, b, n)))(vb, bb)
    for k in range(3):
        ak = a + (float(scale[k]) - 1.0) * np.diag(np.diag(a))
        assert np.max(np.abs(ak @ np.asarray(xb[k]) - np.asarray(bb[k]))) <= 1e-12
        assert np.max(np.abs(ak.T @ np.asarray(yb[k]) - np.asarray(bb[k]))) <= 1e-12
