"""Independent reference: the uniaxial Anand equations integrated by SciPy's Radau.

Uniaxial compression at constant true strain rate with a traction-free side is, for the
hypoelastic (Jaumann) law with isotropic moduli, exactly (compression positive)

    d(sigma)/dt = E (rate - f(sigma, s)),   ds/dt = g(sigma, s),   d(eqps)/dt = f(sigma, s)

with E = 9KG/(3K+G), f and g the Anand functions (thesis eqs. 6.1-6.3, errata item 3).
This file is written with NumPy/SciPy only and shares no code with jaxform.
"""

import numpy as np
from scipy.integrate import solve_ivp

AL1100 = dict(
    A=4.75e-7,
    xi=7.0,
    m=0.23348,
    s0=29.7,
    h0=1115.6,
    s_hat=18.92,
    n=0.07049,
    a=1.3,
    G=20200.0,
    K=66000.0,
)


def anand_uniaxial_reference(rate, strains, p=AL1100, rtol=1e-10, speed_over_height=None):
    """Stress, s and eqps at the given true strains (array, increasing from 0).

    With ``speed_over_height = v/H`` (1/s) the loading is a constant ram speed instead:
    true strain rate v/(H - v t), strain -ln(1 - v t/H).
    """
    E = 9.0 * p["K"] * p["G"] / (3.0 * p["K"] + p["G"])

    def f(sig, s):
        x = np.clip(p["xi"] * sig / s, 0.0, 150.0)
        return p["A"] * np.sinh(x) ** (1.0 / p["m"])

    def strain_rate(t):
        if speed_over_height is None:
            return rate
        return speed_over_height / (1.0 - speed_over_height * t)

    def rhs(t, y):
        sig, s, ep = y
        rate_t = strain_rate(t)
        fr = f(sig, s)
        s_star = p["s_hat"] * (max(fr, 1e-300) / p["A"]) ** p["n"]
        u = 1.0 - s / s_star
        g = p["h0"] * np.sign(u) * abs(u) ** p["a"] * fr
        return [E * (rate_t - fr), g, fr]

    if speed_over_height is None:
        t_eval = np.asarray(strains) / rate
    else:
        t_eval = -np.expm1(-np.asarray(strains)) / speed_over_height
        rate = speed_over_height
    sol = solve_ivp(
        rhs,
        (0.0, t_eval[-1]),
        [0.0, p["s0"], 0.0],
        method="Radau",
        t_eval=t_eval,
        rtol=rtol,
        atol=[1e-12, 1e-12, 1e-14],
        first_step=1e-9 / rate,
    )
    assert sol.success, sol.message
    return sol.y
