"""Modified Newton: one factorization kept across iterations and load steps (issue 7).

References: full Newton on the same problem (the kept factorization changes the path, not
the root: both stop at ||R|| <= rtol F), an algebraic system with a known root, and the
configuration contract (a backend that cannot keep a factorization is refused by name).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_upsetting import scene, seed_run

from jaxform.config import ConfigError
from jaxform.linear import KLU, DenseLU
from jaxform.simulation import simulate
from jaxform.solver import Kept, NewtonSettings, choose_method, modified_newton, newton
from jaxform.status import OK

N = 6
RNG = np.random.default_rng(7)
A = jnp.asarray(np.eye(N) * 4.0 + RNG.uniform(-1.0, 1.0, (N, N)))  # not symmetric
B = jnp.asarray(RNG.uniform(-2.0, 2.0, N))
ROWS, COLS = (
    jnp.asarray(a.ravel()) for a in np.meshgrid(np.arange(N), np.arange(N), indexing="ij")
)


def residual(x):  # R(x) = A x + x^3 - b: one root near A^-1 b, Jacobian A + 3 diag(x^2)
    r = A @ x + x**3 - B
    return r, jnp.sum(x), jnp.asarray(OK), jnp.asarray(1.0)


def residual_and_jacobian(x):
    r, aux, code, scale = residual(x)
    return r, jax.jacfwd(lambda y: residual(y)[0])(x).ravel(), aux, code, scale


@pytest.mark.parametrize("backend", ["dense", "sparse"])
def test_modified_newton_finds_the_newton_root_with_fewer_factorizations(backend):
    """Same root as full Newton to 1e-13 (rtol 1e-14 of a unit force scale), fewer
    factorizations than iterations, and the last factorization handed back for reuse.
    Full Newton with factorizations kept takes full Newton's iterates."""
    lin = {"dense": DenseLU, "sparse": KLU}[backend]()
    symbolic = None
    if backend == "sparse":
        from jaxform.klu import symbolic as klu_symbolic

        symbolic = klu_symbolic(ROWS, COLS, N)
    settings = NewtonSettings(rtol=1e-14, method="modified")

    @jax.jit
    def solve(x0, fac):
        return modified_newton(
            residual,
            residual_and_jacobian,
            Kept(
                lambda vals, old: lin.refactor(ROWS, COLS, vals, N, symbolic, old),
                lambda f, b: lin.solve_factored(f, b, symbolic),
                fac,
            ),
            x0,
            settings,
        )

    x, aux, its, code, hist, fac = solve(jnp.zeros(N), lin.empty_factorization(N, B.dtype))
    x_ref, _, its_ref, code_ref, hist_ref, none = newton(
        residual,
        residual_and_jacobian,
        lambda v, b: lin.solve(ROWS, COLS, v, b, N),
        jnp.zeros(N),
        NewtonSettings(rtol=1e-14),
    )
    assert none is None
    # full Newton that factors, solves with the factors and hands back the last
    # factorization (what a gradient run keeps for its reverse pass): the same iterates
    x_k, _, its_k, code_k, hist_k, fac_k = jax.jit(
        lambda x0, fac: newton(
            residual,
            residual_and_jacobian,
            None,
            x0,
            NewtonSettings(rtol=1e-14),
            kept=Kept(
                lambda vals, old: lin.refactor(ROWS, COLS, vals, N, symbolic, old),
                lambda f, b: lin.solve_factored(f, b, symbolic),
                fac,
            ),
        )
    )(jnp.zeros(N), lin.empty_factorization(N, B.dtype))
    assert int(code_k) == OK and int(its_k) == int(its_ref)
    np.testing.assert_allclose(np.asarray(hist_k), np.asarray(hist_ref), rtol=1e-12)
    assert float(jnp.max(jnp.abs(x_k - x_ref))) <= 1e-15
    assert bool(fac_k.valid) and int(fac_k.count) == int(its_ref)  # one per iteration
    jax.block_until_ready(lin.release(fac_k))
    assert int(code) == OK and int(code_ref) == OK
    assert float(jnp.max(jnp.abs(x - x_ref))) <= 1e-13
    assert float(jnp.max(jnp.abs(residual(x)[0]))) <= 1e-13
    assert float(aux) == pytest.approx(float(jnp.sum(x)), abs=0.0)
    assert bool(fac.valid) and 1 <= int(fac.count) < int(its)
    # a second solve from another start reuses the kept factorization first
    x2, _, its2, code2, _, fac2 = solve(0.5 * x, fac)
    assert int(code2) == OK and float(jnp.max(jnp.abs(x2 - x_ref))) <= 1e-13
    assert int(fac2.count) - int(fac.count) < int(its2)
    jax.block_until_ready(lin.release(fac2))


def test_modified_newton_on_seed_scene_matches_full_newton():
    """klujax kept across steps: the same force history and final unknowns as full Newton
    to 1e-9 relative (both stop at rtol = 1e-10 of the force scale; measured 3.6e-11 on
    this scene), with more, cheaper iterations and at most a tenth of the factorizations."""
    sc, ref = seed_run()
    res = simulate(scene("solver.newton=modified"))
    assert res.scene.newton.method == "modified" and res.scene.linear.backend == "sparse"
    f, f_ref = res.history["force_N"][1:], ref.history["force_N"][1:]
    assert np.max(np.abs(f - f_ref) / np.abs(f_ref)) <= 1e-9
    u, u_ref = res.fields["x"][-1], ref.fields["x"][-1]
    assert np.max(np.abs(u - u_ref)) <= 1e-9 * np.max(np.abs(u_ref))
    n_fac = res.history["factorizations"].sum()
    assert 1 <= n_fac <= 0.1 * ref.history["factorizations"].sum()
    assert np.array_equal(ref.history["factorizations"], ref.history["newton_iterations"])


def test_modified_newton_cuts_back_and_completes():
    """dt = 10 s with 2 new Jacobians (and 6 more iterations) allowed: steps fail with a
    kept factorization, are halved, the factorization survives the failure (klujax: no
    double free, no use after free), the run completes (11 cutbacks measured)."""
    sc = scene(
        "mesh.nr=3",
        "mesh.nz=3",
        "time.dt_s=10.0",
        "solver.max_newton_iterations=2",
        "solver.chunk_steps=4",
        "die.reduction=0.3",
        "solver.linear=sparse",
        "solver.newton=modified",
    )
    res = simulate(sc)
    assert res.history["cutbacks"].sum() > 0
    assert abs(res.history["stroke_mm"][-1] - 0.3 * 7.5) <= 1e-12
    assert np.all(np.isfinite(res.history["force_N"]))


def test_backend_that_cannot_keep_a_factorization_is_refused():
    with pytest.raises(ConfigError, match="solver.newton = 'modified'.*jax-sparse"):
        scene("solver.linear=jax-sparse", "solver.newton=modified")
    with pytest.raises(ValueError, match="solver.newton = 'secant'"):
        choose_method("secant", KLU(), 10)


def test_auto_picks_modified_newton_for_large_sparse_systems():
    from jaxform.solver import MODIFIED_MIN_UNKNOWNS as M

    assert choose_method("auto", KLU(), M) == "modified"
    assert choose_method("auto", KLU(), M - 1) == "newton"
    assert choose_method("auto", DenseLU(), 10 * M) == "newton"
    assert choose_method("newton", KLU(), 10 * M) == "newton"
