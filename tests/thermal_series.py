"""Independent references for transient heat conduction: the classical series solutions
(Carslaw & Jaeger, Conduction of Heat in Solids, 1959; Incropera & DeWitt, ch. 5) of a body
at a uniform initial temperature cooling by convection (a Robin boundary) into a medium at
T_inf.  theta = (T - T_inf) / (T_0 - T_inf), Bi = h L / k, Fo = alpha t / L^2.

* plane slab of half-thickness L, centre plane adiabatic (symmetry), face x = L convective:
      theta = sum_n C_n exp(-z_n^2 Fo) cos(z_n x / L),   z_n tan z_n = Bi,
      C_n = 4 sin z_n / (2 z_n + sin 2 z_n);
* infinite cylinder of radius R, convective surface:
      theta = sum_n C_n exp(-z_n^2 Fo) J0(z_n r / R),    z_n J1(z_n) / J0(z_n) = Bi,
      C_n = (2 / z_n) J1(z_n) / (J0(z_n)^2 + J1(z_n)^2).

Written with NumPy/SciPy only (no jaxform code); 200 terms (the first terms dominate for
Fo > 0.01)."""

import numpy as np
from scipy.optimize import brentq
from scipy.special import j0, j1

N_TERMS = 200


def _roots(f, brackets):
    return np.array([brentq(f, a, b, xtol=1e-15) for a, b in brackets])


def slab_theta(x_over_l, fo, bi):
    """theta of the slab at x / L (array) and Fourier number fo."""
    eps = 1e-12
    brackets = [(n * np.pi + eps, n * np.pi + np.pi / 2 - eps) for n in range(N_TERMS)]
    z = _roots(lambda z: z * np.tan(z) - bi, brackets)
    c = 4.0 * np.sin(z) / (2.0 * z + np.sin(2.0 * z))
    x = np.asarray(x_over_l, dtype=float)[..., None]
    return np.sum(c * np.exp(-(z**2) * fo) * np.cos(z * x), axis=-1)


def cylinder_theta(r_over_r, fo, bi):
    """theta of the infinite cylinder at r / R (array) and Fourier number fo."""
    # z J1 - Bi J0 changes sign between consecutive zeros of J1 (0 and then 3.83, 7.02, ...)
    grid = np.linspace(1e-9, (N_TERMS + 2) * np.pi, 200 * (N_TERMS + 2))
    g = grid * j1(grid) - bi * j0(grid)
    idx = np.nonzero(np.sign(g[:-1]) != np.sign(g[1:]))[0][:N_TERMS]
    z = _roots(lambda z: z * j1(z) - bi * j0(z), [(grid[i], grid[i + 1]) for i in idx])
    c = 2.0 / z * j1(z) / (j0(z) ** 2 + j1(z) ** 2)
    r = np.asarray(r_over_r, dtype=float)[..., None]
    return np.sum(c * np.exp(-(z**2) * fo) * j0(z * r), axis=-1)
