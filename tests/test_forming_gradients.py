"""Exact gradients of the damage, wear and forming-energy objectives (issue 40 part 6).

Reference: central finite differences of the same differentiable run (float64), step h =
1e-4 relative in the friction coefficient and in Anand's s0 (truncation error O(h^2)
~ 1e-8 relative; no contact node changes state within the step on this scene, which
the test asserts).  One small scene (3 x 3 q1p0 billet, Coulomb 0.3, 30 % in 10 steps,
wear on) is run as one vjp whose pullback gives the three objectives' gradients (one
forward and one reverse program for all).
"""

from dataclasses import replace
from functools import cache

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxform.config import ConfigError, check_gradient_run, load_config
from jaxform.design.objectives import ForgingWork, MaxDamage, WearDepth, power_mean
from jaxform.design.problem import build_objective
from jaxform.gradients import trajectory
from jaxform.scenes import build_scene

BASE = {
    "billet": {"diameter_mm": 5.0, "height_mm": 7.5},
    "mesh": {"nr": 3, "nz": 3, "element": "q1p0"},
    "die": {"speed_mm_s": 0.075, "reduction": 0.3},
    "friction": {"model": "coulomb", "mu": 0.3},
    "wear": {"on": True, "k": 1e-3, "hardness_MPa": 2000.0},
    "time": {"dt_s": 3.0},
    "output": {"fields": False, "plots": False},
}
OBJECTIVES = (MaxDamage(0), WearDepth(), ForgingWork())
U0 = np.array([0.3, 1.0])  # (mu, factor on Anand's s0)


@cache
def scene():
    return build_scene(load_config(BASE))


def _run(u):
    sc = scene()
    inp = sc.inputs
    die = inp.die.replace_each(lambda d: replace(d, friction=replace(d.friction, mu=u[0])))
    params = replace(inp.params, s0_MPa=inp.params.s0_MPa * u[1])
    traj = trajectory(sc, replace(inp, die=die, params=params))
    values = jnp.stack([o(traj, inp) for o in OBJECTIVES])
    return values, (traj.codes, traj.contact_status)


@cache
def exact():
    values, pull, (codes, status) = jax.vjp(_run, jnp.asarray(U0), has_aux=True)
    assert np.all(np.asarray(codes) == 0)
    grads = np.array([np.asarray(pull(jnp.eye(3)[i])[0]) for i in range(3)])
    return np.asarray(values), grads, np.asarray(status)


@pytest.mark.slow  # ~3 min cold on 2 shared cores (a vjp and a forward program compiled)
@pytest.mark.parametrize("i", [0, 1])  # d/d mu, d/d s0 factor
def test_objective_gradients_against_central_differences(i):
    """Each objective's dJ/du_i against (J(u + h e_i) - J(u - h e_i)) / 2h, h = 1e-4 u_i:
    relative error <= 1e-5 (damage, wear, forming energy; all three derivatives nonzero).
    Measured 2026-11-26: at most 6e-7 (e.g. d max_damage / d mu 0.0977521 exact,
    0.0977521 FD; d wear / d mu -7.43374e-6 both)."""
    values, grads, status = exact()
    assert values[0] > 0.0 and values[1] > 0.0 and values[2] > 0.0
    h = 1e-4 * U0[i]
    fd = []
    for s in (1.0, -1.0):
        u = U0.copy()
        u[i] += s * h
        v, (codes, st) = _run(jnp.asarray(u))
        assert np.all(np.asarray(codes) == 0)
        assert np.array_equal(np.asarray(st), status)  # the same active set
        fd.append(np.asarray(v))
    fd = (fd[0] - fd[1]) / (2.0 * h)
    for k, obj in enumerate(OBJECTIVES):
        assert grads[k, i] != 0.0, type(obj).__name__
        assert abs(fd[k] - grads[k, i]) <= 1e-5 * abs(grads[k, i]), (obj, fd[k], grads[k, i])


def test_power_mean_is_a_smooth_max():
    """Between N^(-1/p) max and max (reference: the definition), exact for equal values,
    finite gradient at all zeros."""
    v = jnp.asarray([0.0, 0.1, 0.5, 0.2])
    m = float(power_mean(v, 8.0))
    assert 0.5 * 4 ** (-1 / 8) <= m <= 0.5
    assert float(power_mean(jnp.full(5, 0.3), 8.0)) == pytest.approx(0.3, rel=1e-14)
    g = jax.grad(lambda x: power_mean(x, 8.0))(jnp.zeros(3))
    assert np.all(np.isfinite(np.asarray(g)))


def test_objectives_from_the_config():
    """design.objective = max_damage / wear_depth build the objectives of this module;
    wear_depth without wear.on is refused before anything runs."""
    sc = build_scene(load_config(BASE, ["design.objective=max_damage",
                                        "output.damage_criterion=brozzo"]))  # fmt: skip
    o = build_objective(sc)
    assert isinstance(o, MaxDamage) and o.criterion == 1 and o.p == 8.0
    sc = build_scene(load_config(BASE, ["design.objective=wear_depth", "design.smooth_max_p=4"]))
    assert isinstance(build_objective(sc), WearDepth) and build_objective(sc).p == 4.0
    cfg = load_config(BASE, ["design.objective=wear_depth", "wear.on=false"])
    with pytest.raises(ConfigError, match="wear.on"):
        check_gradient_run(cfg)


@pytest.mark.slow  # the remeshed gradient programs: several minutes on 2 shared cores
def test_damage_gradient_through_remeshes_against_central_differences():
    """max_damage through 3 remeshes (3 x 3 q1p0, Coulomb 0.3, 30 % in 20 steps, a new mesh
    every 5): the damage is carried by the remesh maps, so its gradient in the friction
    coefficient matches central differences (h = 1e-4, relative error <= 1e-5; measured
    2026-11-26: 1.3e-8, 0.0222430 exact against 0.0222430 FD in the scaled variable)."""
    from fd_check import directional_derivatives

    from jaxform.design import build_problem

    over = dict(BASE, time={"dt_s": 1.5}, remesh={"every_steps": 5, "element_size_mm": 1.5})
    sc = build_scene(load_config(over))
    pb = build_problem(sc, groups=("friction",), objective=MaxDamage(0), single_program=True)
    assert len(pb.plan.segments) == 4
    _, grad, _ = pb.value_and_grad(pb.start)
    exact, fd = directional_derivatives(pb, grad, "friction")
    assert exact != 0.0
    assert abs(fd - exact) <= 1e-5 * abs(exact), (fd, exact)
