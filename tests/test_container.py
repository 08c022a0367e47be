"""Two dies at one node: a workpiece node pressed into the corner of two dies carries both
dies' forces (``die.contact_pairs = "each_die"``: one multiplier pair per node and die).

References: uniaxial strain in a frictionless container (a J2 solid of yield stress
sigma_y compressed by a flat die with its side held by the container wall, r = R: the
state is homogeneous with sigma_r = sigma_theta and sigma_z - sigma_r = -sigma_y once it
yields, so the punch pressure F_top / (pi R^2) exceeds the wall pressure F_wall / (2 pi R
h) by exactly sigma_y; equilibrium of nodal forces makes both sums exact); static
equilibrium of the workpiece (top die = mid-plane reaction + the wall's vertical
friction force); central differences for the gradient."""

from __future__ import annotations

from functools import cache

import jax.numpy as jnp
import numpy as np
import pytest
from fd_check import directional_derivatives

from jaxform.assembly import internal_forces
from jaxform.capacity import padded
from jaxform.config import load_config
from jaxform.contact import EachDie
from jaxform.design import build_problem
from jaxform.design.objectives import ForgingWork
from jaxform.postprocess import positions
from jaxform.scenes import build_scene
from jaxform.simulation import simulate

R, H = 5.0, 10.0  # billet radius and height (mm); the half-height model is 5 mm high
SIGMA_Y = 100.0  # MPa, the yield stress of the j2_perfect_100MPa preset
CONTAINER = {
    "billet": {"diameter_mm": 2 * R, "height_mm": H},
    "mesh": {"nr": 3, "nz": 3, "element": "q1p0"},
    "material": {"preset": "j2_perfect_100MPa"},
    "die": {"speed_mm_s": 0.1, "reduction": 0.02, "contact_pairs": "each_die"},
    # the container wall at r = R, walked downwards (the billet inside, on its right)
    "side_die": {"profile_mm": [[R, 6.0], [R, 0.0]]},
    "friction": {"model": "none"},
    "time": {"dt_s": 0.25},
    "output": {"plots": False},
}
WALL_FRICTION = ("side_die.friction.model=coulomb", "side_die.friction.mu=0.2")


@cache
def _run(overrides: tuple[str, ...] = ()):
    sc = build_scene(load_config(CONTAINER, overrides))
    return sc, simulate(sc)


def _reaction(sc, res) -> float:
    """The mid-plane's vertical reaction (N): the internal forces on its u_z rows."""
    st = res.final_state
    f_int = internal_forces(sc.model, st.x, st.gauss, sc.inputs.coords, 1e-30,
                            sc.inputs.params, sc.idx)  # fmt: skip
    return float(jnp.sum(f_int[sc.idx.bottom_reaction_dofs]))


def test_candidates_are_node_die_pairs():
    """Every contact node is a candidate of each die (top, side) once; the corner-contact
    facets and the contact areas' facets follow (each facet joins two candidates of its
    own die)."""
    sc = build_scene(load_config(CONTAINER))
    assert isinstance(sc.model.contact.pairing, EachDie)
    nodes, die = np.asarray(sc.idx.contact_nodes), np.asarray(sc.idx.contact_die)
    n = len(nodes) // 2
    assert sc.inputs.die.names == ("top", "side") and len(nodes) == 2 * n
    np.testing.assert_array_equal(nodes[:n], nodes[n:])
    np.testing.assert_array_equal(die, np.repeat([0, 1], n))
    assert len(set(nodes[:n].tolist())) == n
    facets = np.asarray(sc.idx.contact_facets)
    np.testing.assert_array_equal(die[facets[:, 0]], die[facets[:, 1]])
    # the nearest-die scene: one candidate per node
    near = build_scene(load_config(CONTAINER, ("die.contact_pairs=nearest",)))
    assert near.model.layout.n_contact == n


def test_corner_node_carries_both_dies_and_the_wall_force_is_the_closed_form():
    """A J2 billet (sigma_y = 100 MPa) compressed 2 % in a frictionless container: the
    node in the corner of the top die and the wall carries both dies' normal forces (> 1 %
    of the mean nodal force each); no node leaves the container (r <= R + 1e-9 mm); the
    punch pressure exceeds the wall pressure by sigma_y (closed form of uniaxial strain,
    1e-9 relative); the top force equals the mid-plane reaction (equilibrium, 1e-8)."""
    sc, res = _run()
    assert res.failure is None
    x = np.asarray(res.fields["x"][-1])
    pos = positions(sc, x)
    lam = np.asarray(sc.model.layout.node_multipliers(x))
    nodes, die = np.asarray(sc.idx.contact_nodes), np.asarray(sc.idx.contact_die)
    corner = int(np.argmax(pos[:, 0] + pos[:, 1]))  # the top outer corner
    assert pos[corner, 0] == pytest.approx(R, abs=1e-9)
    top_force = res.history["force_N"][-1]
    both = lam[nodes == corner, 0]
    assert both.shape == (2,) and np.all(both > 0.01 * top_force / (sc.mesh.n_nodes**0.5))
    assert pos[:, 0].max() <= R + 1e-9
    h = pos[:, 1].max()  # the half height now (mm)
    assert h == pytest.approx(0.5 * H * (1.0 - 0.02), abs=1e-9)
    wall = lam[die == 1, 0].sum()  # the wall's radial force (N, over the circumference)
    p_top, p_wall = top_force / (np.pi * R**2), wall / (2.0 * np.pi * R * h)
    assert p_top - p_wall == pytest.approx(SIGMA_Y, rel=1e-9)
    assert p_wall > 10.0 * SIGMA_Y  # the container holds a large lateral stress
    assert abs(_reaction(sc, res) - top_force) <= 1e-8 * top_force


@pytest.mark.slow
def test_wall_friction_balances_the_top_die():
    """With Coulomb 0.2 at the wall the wall holds the material back: the top die's force
    equals the mid-plane reaction plus the wall's vertical force (equilibrium, 1e-8 of the
    top force), the wall's share more than 1 %; the corner node carries both dies."""
    sc, res = _run(WALL_FRICTION)
    assert res.failure is None
    h = res.history
    top, side = h["force_top_N"][-1], h["force_side_N"][-1]
    assert abs(side) > 0.01 * top
    assert abs(_reaction(sc, res) - (top + side)) <= 1e-8 * top
    status = np.asarray(res.fields["contact_status"][-1])
    nodes = np.asarray(sc.idx.contact_nodes)
    pos = positions(sc, res.fields["x"][-1])
    corner = int(np.argmax(pos[:, 0] + pos[:, 1]))
    assert np.all(status[nodes == corner] > 0)


def test_padding_keeps_the_pairs():
    """The scene padded to its capacity bucket: the real candidates keep their node and
    die, the ghosts are die 0's; a state padded and trimmed comes back unchanged."""
    sc, res = _run()
    p = padded(sc)
    n = sc.model.layout.n_contact
    pid = np.asarray(p.scene.idx.contact_die)
    np.testing.assert_array_equal(pid[:n], np.asarray(sc.idx.contact_die))
    np.testing.assert_array_equal(np.asarray(p.scene.idx.contact_nodes)[:n],
                                  np.asarray(sc.idx.contact_nodes))  # fmt: skip
    assert np.all(pid[n:] == 0)
    back = p.trim(p.state(res.final_state))
    np.testing.assert_array_equal(np.asarray(back.x), np.asarray(res.final_state.x))
    np.testing.assert_array_equal(np.asarray(back.slip_mm), np.asarray(res.final_state.slip_mm))


@pytest.mark.slow
def test_gradient_with_pairs_against_central_differences():
    """The forging work of the container scene with wall friction (pairs): its derivative
    along a random direction of the friction group against central differences (h = 1e-4,
    relative error <= 1e-5)."""
    pb = build_problem(build_scene(load_config(CONTAINER, WALL_FRICTION)), groups=("friction",),
                       objective=ForgingWork(), single_program=True)  # fmt: skip
    _, grad, _ = pb.value_and_grad(pb.start)
    exact, fd = directional_derivatives(pb, grad, "friction")
    assert abs(exact - fd) <= 1e-5 * abs(fd), (exact, fd)


PUNCH_MM, CONTAINER_MM = 3.5, 5.0  # radii of configs/backward_extrusion.toml


def johnson_punch_pressure(flow_stress_MPa: float) -> float:
    """The punch pressure of backward (indirect) extrusion (MPa) by Johnson's extrusion
    strain, p = Y (a + b ln R), a = 0.8, b = 1.5 (M. P. Groover, Fundamentals of Modern
    Manufacturing, section "Analysis of extrusion": the extrusion strain
    eps_x = a + b ln r_x and, for indirect extrusion, p = Y_f eps_x), with the extrusion
    ratio R = A_0 / A_f = container area / the cup wall's annulus."""
    ratio = CONTAINER_MM**2 / (CONTAINER_MM**2 - PUNCH_MM**2)
    return flow_stress_MPa * (0.8 + 1.5 * np.log(ratio))


@pytest.mark.slow
def test_backward_extrusion_start_pressure_and_equilibrium():
    """configs/backward_extrusion.toml with the J2 verification material (sigma_0 = 100
    MPa, no hardening, no rate effect: the flow stress is known), the first 0.5 mm of
    the punch's stroke (before its first remesh): at every step the bottom die carries the
    punch's force plus the container wall's (its friction holds the rising cup wall back;
    equilibrium, 1 % of the punch force); the punch pressure is above the ideal-work
    bound sigma_0 ln R (no process extrudes with less than the homogeneous work) and has
    levelled off (the last two steps within 2 %), between Johnson's p = sigma_0 (0.8 +
    1.5 ln R) and 1.6 times it (measured 1.38: Johnson's constants are fitted to forward
    extrusion through a square die, without the punch face's friction and the turn of the
    flow into the cup wall; a reference, not a bound; docs: scenes)."""
    cfg = load_config("configs/backward_extrusion.toml",
                      ("output.plots=false", "material.preset=j2_perfect_100MPa",
                       "die.reduction=0.0625"))  # fmt: skip
    res = simulate(build_scene(cfg))
    assert res.failure is None
    h = res.history
    top, bottom, side = h["force_top_N"], h["force_bottom_N"], h["force_side_N"]
    assert h["stroke_mm"][-1] == pytest.approx(0.5, rel=1e-9)
    assert np.max(np.abs(bottom - top - side)) <= 0.01 * np.max(top)
    p = top / (np.pi * PUNCH_MM**2)
    ratio = CONTAINER_MM**2 / (CONTAINER_MM**2 - PUNCH_MM**2)
    assert p[-1] > SIGMA_Y * np.log(ratio)
    assert abs(p[-1] - p[-2]) <= 0.02 * p[-1]
    assert 1.0 < p[-1] / johnson_punch_pressure(SIGMA_Y) < 1.6
