"""Shared check: assembled (jacfwd) global Jacobian against central finite differences."""

import jax
import jax.numpy as jnp
import numpy as np


def jacobian_fd_error(sc, x, ctx, h_rel):
    """Frobenius relative error of the assembled Jacobian at x against 4-point central
    differences of the global residual, step h_rel x max(|x_j|, 1e-3) per unknown.
    ``ctx``: the step's StepContext (jaxform.stepping.step_context)."""
    _, vals, *_ = jax.jit(sc.model.residual_and_jacobian)(x, ctx)
    n = sc.model.layout.n_dofs
    jac = np.zeros((n, n))
    jac[np.asarray(sc.idx.rows), np.asarray(sc.idx.cols)] = np.asarray(vals)
    res_fn = jax.jit(lambda y: sc.model.residual(y, ctx)[0])
    scale = np.maximum(np.abs(np.asarray(x)), 1e-3)
    fd = np.zeros((n, n))
    for j in range(n):
        hj = h_rel * scale[j]
        e = jnp.zeros(n).at[j].set(hj)
        f = [np.asarray(res_fn(x + k * e)) for k in (2, 1, -1, -2)]
        fd[:, j] = (-f[0] + 8 * f[1] - 8 * f[2] + f[3]) / (12 * hj)
    return np.linalg.norm(jac - fd) / np.linalg.norm(fd)


def directional_derivatives(problem, grad, group, seed=7, h=1e-4):
    """(exact, central difference) of a design problem's objective along a random unit
    direction (seeded) of design group ``group`` at its start: dJ/du . du against
    (J(u + h du) - J(u - h du)) / 2h (truncation error O(h^2))."""
    rng = np.random.default_rng(seed)
    u = {k: np.asarray(v) for k, v in problem.start.items()}
    du = rng.standard_normal(u[group].shape)
    du /= np.linalg.norm(du)  # unit direction: no accidentally tiny derivative
    exact = float(np.dot(np.asarray(grad[group]), du))
    vals = []
    for s in (1.0, -1.0):
        d = dict(u)
        d[group] = u[group] + s * h * du
        vals.append(float(problem.value(d)[0]))
    return exact, (vals[0] - vals[1]) / (2 * h)
