"""Several rigid dies: a full-height workpiece between a top and a bottom die, a side die
(mandrel), and the asymmetric closed-die part.

References: the half-height model (a full-height billet between mirrored dies moving
symmetrically is the half model and its mirror image, so the force is the same to the
Newton tolerance); static equilibrium of the workpiece (the forces of the dies and the
support reaction balance); the mandrel's surface (no penetration)."""

from __future__ import annotations

from functools import cache

import jax.numpy as jnp
import numpy as np
import pytest
from cli_harness import assert_refused
from fd_check import directional_derivatives

from jaxform.assembly import internal_forces
from jaxform.config import load_config
from jaxform.design import build_problem
from jaxform.design.objectives import ForgingWork
from jaxform.dies import DieSet
from jaxform.errors import ConfigError
from jaxform.postprocess import positions
from jaxform.scenes import build_scene
from jaxform.simulation import simulate

BILLET = {
    "billet": {"diameter_mm": 10.0, "height_mm": 10.0},
    "mesh": {"nr": 4, "nz": 3, "element": "q1p0"},
    "material": {"preset": "al1100_673K"},
    "die": {"speed_mm_s": 1.0, "reduction": 0.3},
    "friction": {"model": "coulomb", "mu": 0.3},
    "time": {"dt_s": 0.5},
    "output": {"plots": False},
    # the half model's 56 unknowns solve by dense LU and the twin's 100 by klujax, where
    # 'auto' would keep a factorization: one method for both, that the two runs step alike
    "solver": {"newton": "newton"},
}
# the full-height twin: twice the elements over twice the height, the bottom die the top
# die's mirror image rising at half the ram speed
TWIN = (
    "billet.full_height=true",
    "mesh.nz=6",
    "bottom_die.mirror=true",
    "bottom_die.speed_share=0.5",
)


@cache
def _run(overrides: tuple[str, ...] = ()):
    sc = build_scene(load_config(BILLET, overrides))
    return sc, simulate(sc)


def test_full_height_twin_equals_half_model():
    """Force and stroke of the full-height twin equal the half model's to 1e-8 (relative
    to the peak force); the bottom die carries the top die's force (equilibrium, 1e-8)."""
    _, half = _run()
    sc, full = _run(TWIN)
    assert isinstance(sc.inputs.die, DieSet) and not sc.symmetric_z
    assert "symmetry" not in sc.mesh.node_sets
    h, f = half.history, full.history
    assert len(h["time_s"]) == len(f["time_s"]) >= 5
    np.testing.assert_allclose(f["time_s"], h["time_s"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(f["stroke_mm"], h["stroke_mm"], rtol=0, atol=1e-12)
    peak = np.max(h["force_N"])
    assert peak > 1000.0
    assert np.max(np.abs(f["force_N"] - h["force_N"])) <= 1e-8 * peak
    assert np.max(np.abs(f["force_top_N"] - f["force_bottom_N"])) <= 1e-8 * peak
    np.testing.assert_array_equal(f["force_top_N"], f["force_N"])
    # the deformed section is the half model's and its mirror image
    top = positions(sc, full.fields["x"][-1])
    half_sc, _ = _run()
    ref = positions(half_sc, half.fields["x"][-1])
    upper = top[top[:, 1] >= -1e-9]
    key = np.lexsort((np.round(upper[:, 0], 6), np.round(upper[:, 1], 6)))
    key_ref = np.lexsort((np.round(ref[:, 0], 6), np.round(ref[:, 1], 6)))
    np.testing.assert_allclose(upper[key], ref[key_ref], rtol=0, atol=1e-8)


def test_a_replays_schedule_comes_from_full_newton():
    """The forward run that fixes a differentiable replay's steps solves by full Newton,
    the replay's method, whatever ``solver.newton`` says.  On the twin, 'auto' keeps a
    factorization (klujax, 100 unknowns) and takes the first 0.5 s step whole, where
    full Newton cuts it back to 0.25 s (measured: 25 iterations against 43 and a
    cutback), so a replay on modified Newton's steps would fail its first step.  The
    schedule is full Newton's from the replay's start, the step from rest without a
    probe: that of ``_run(TWIN)`` with time.first_step_probe = 0 (BILLET sets
    solver.newton).  With the probe, full Newton too takes the first step whole."""
    from jaxform.gradients import schedule
    from jaxform.solver import ModifiedNewton

    sc = build_scene(load_config(BILLET, TWIN + ("solver.newton=auto",)))
    assert isinstance(sc.newton.variant, ModifiedNewton)
    _, full = _run((*TWIN, "time.first_step_probe=0"))
    times = schedule(sc)
    np.testing.assert_allclose(times, full.history["time_s"][1:], rtol=0, atol=1e-12)
    assert times[0] == 0.25
    assert _run(TWIN)[1].history["time_s"][1] == 0.5


def test_fixed_anvil_stroke_and_forces():
    """A billet on a fixed bottom die: the top die makes the whole stroke at the ram speed
    (the run ends at reduction x H / v), the bottom die stays put, and the two dies carry
    equal forces (equilibrium, 1e-8 of the peak)."""
    sc, res = _run(("billet.full_height=true", "mesh.nz=6"))
    h = res.history
    assert sc.t_end == pytest.approx(0.3 * 10.0 / 1.0, rel=1e-12)
    assert h["stroke_mm"][-1] == pytest.approx(3.0, rel=1e-12)
    bottom = sc.inputs.die.dies[1]
    assert float(bottom.travel(sc.t_end)) == 0.0
    peak = np.max(h["force_N"])
    assert np.max(np.abs(h["force_top_N"] - h["force_bottom_N"])) <= 1e-8 * peak
    # no node below the fixed bottom face z = -5 mm (contact holds it: 1e-8 mm)
    pos = positions(sc, res.fields["x"][-1])
    assert pos[:, 1].min() >= -5.0 - 1e-8


def test_bottom_die_path_tables_set_the_end():
    """With path tables the stroke is the top die's travel plus the bottom die's rise:
    2 mm and 1 mm over 10 s close 1.5 mm (reduction 0.15 of 10 mm) at 5 s."""
    cfg = load_config(
        BILLET,
        (
            "billet.full_height=true",
            "mesh.nz=6",
            "die.path_time_s=[0.0, 10.0]",
            "die.path_travel_mm=[0.0, 2.0]",
            "bottom_die.path_time_s=[0.0, 10.0]",
            "bottom_die.path_travel_mm=[0.0, 1.0]",
            "die.reduction=0.15",
        ),
    )
    sc = build_scene(cfg)
    assert sc.t_end == pytest.approx(5.0, rel=1e-12)
    assert float(sc.inputs.die.stroke(sc.t_end)) == pytest.approx(1.5, rel=1e-12)
    assert float(sc.inputs.die.dies[1].travel(sc.t_end)) == pytest.approx(-0.5, rel=1e-12)


def test_side_die_follows_its_path_table():
    """A side die on a path table: its travel at t is the table's (0.5 mm at 1 s of
    [0, 2] s -> [0, 1] mm), the other dies' are unchanged, the stroke the top die's."""
    sc = build_scene(load_config(BILLET, (
        "side_die.profile_mm=[[6.0, 6.0], [6.0, 0.0]]",
        "side_die.path_time_s=[0.0, 2.0]",
        "side_die.path_travel_mm=[0.0, 1.0]",
    )))  # fmt: skip
    die = sc.inputs.die
    assert die.names == ("top", "side")
    assert float(die.dies[1].travel(1.0)) == pytest.approx(0.5, rel=1e-12)
    assert float(die.stroke(1.0)) == pytest.approx(0.5, rel=1e-12)  # the top die at 0.5 mm/s
    g, n, _ = die.gap(jnp.asarray([5.0, 1.0]), 1.0)  # the billet's side, 1 mm from the wall
    assert float(g) == pytest.approx(1.0, rel=1e-12)
    np.testing.assert_allclose(np.asarray(n), [-1.0, 0.0], atol=1e-15)


RING = {
    "ring": {"outer_diameter_mm": 30.0, "inner_diameter_mm": 15.0, "height_mm": 10.0},
    "mesh": {"nr": 4, "nz": 2, "element": "q1p0"},
    "material": {"preset": "al1100_673K"},
    "die": {"speed_mm_s": 1.0, "reduction": 0.3},
    "friction": {"model": "coulomb", "mu": 0.3},
    "time": {"dt_s": 0.5},
    "output": {"plots": False},
    # the half model's 56 unknowns solve by dense LU and the twin's 100 by klujax, where
    # 'auto' would keep a factorization: one method for both, that the two runs step alike
    "solver": {"newton": "newton"},
}
# a fixed mandrel in the bore (radius 7.5 mm) with 0.5 mm clearance: a vertical line at
# r = 7 mm walked upwards
MANDREL = ("side_die.profile_mm=[[7.0, 0.0], [7.0, 5.0]]",)


def test_mandrel_holds_the_bore_and_balances_forces():
    """Ring 6:3:2 with Coulomb 0.3: without a mandrel the bore shrinks to 12.2 mm at
    mid-height; a fixed mandrel of 14 mm keeps every node at r >= 7 mm (1e-8 mm) and
    carries the friction drag: the mid-plane reaction equals the top die's force plus the
    mandrel's (equilibrium, 1e-8 relative)."""
    free = simulate(build_scene(load_config(RING)))
    assert free.history["inner_diameter_mm"][-1] < 14.0 - 1.0  # the bore closes in
    sc = build_scene(load_config(RING, MANDREL))
    assert sc.inputs.die.names == ("top", "side")
    res = simulate(sc)
    h = res.history
    pos = positions(sc, res.fields["x"][-1])
    assert pos[:, 0].min() >= 7.0 - 1e-8
    assert h["inner_diameter_mm"][-1] == pytest.approx(14.0, abs=2e-8)  # held on the mandrel
    st = res.final_state
    f_int = internal_forces(sc.model, st.x, st.gauss, sc.inputs.coords, 1e-30,
                            sc.inputs.params, sc.idx)  # fmt: skip
    reaction = float(jnp.sum(f_int[sc.idx.bottom_reaction_dofs]))
    top, side = h["force_top_N"][-1], h["force_side_N"][-1]
    assert abs(side) > 1e-3 * top  # the mandrel holds the material back by friction
    assert abs(reaction - (top + side)) <= 1e-8 * top


@pytest.mark.parametrize(
    "overrides, needle",
    [
        (("bottom_die.speed_share=0.5",), "bottom_die.speed_share"),
        (
            (
                "billet.full_height=true",
                "bottom_die.mirror=true",
                "bottom_die.profile_mm=[[0.0, -5.0], [6.0, -5.0]]",
            ),
            "bottom_die.mirror",
        ),  # fmt: skip
        (
            (
                "billet.full_height=true",
                "bottom_die.path_time_s=[0.0, 1.0]",
                "bottom_die.path_travel_mm=[0.0, 1.0]",
            ),
            "bottom_die.path_time_s",
        ),  # fmt: skip
        (("billet.full_height=true", "bottom_die.speed_share=1.0"), "bottom_die.speed_share"),
        (
            ("side_die.path_time_s=[0.0, 1.0]", "side_die.path_travel_mm=[0.0, 1.0]"),
            "side_die.path_time_s",
        ),  # fmt: skip
        (("billet.full_height=true", "mesh.rezone_quality=0.3"), "mesh.rezone_quality"),
    ],
)
def test_bad_die_sets_are_refused(overrides, needle):
    with pytest.raises(ConfigError, match=needle.replace(".", r"\.")):
        load_config(BILLET, overrides)


def test_overlapping_bottom_die_is_refused_on_the_command_line():
    """A bottom die that reaches into the billet at t = 0: one line naming the key."""
    assert_refused(
        [
            "run",
            "configs/upsetting_seed.toml",
            "--set",
            "billet.full_height=true",
            "--set",
            "bottom_die.profile_mm=[[0.0, -3.0], [5.0, -3.0]]",
        ],
        "bottom_die.profile_mm",
    )


@pytest.mark.slow
def test_asymmetric_closed_die_fills_with_flash():
    """configs/closed_die_asymmetric.toml (different top and bottom cavities, a fixed
    bottom die, remeshing): completes with die_fill >= 0.999, flash forming, the two dies'
    forces equal at every step (equilibrium, 1e-7 of the peak), the volume kept to 1e-3."""
    cfg = load_config("configs/closed_die_asymmetric.toml", ("output.plots=false",))
    res = simulate(build_scene(cfg))
    h = res.history
    assert res.failure is None
    assert h["die_fill"][-1] >= 0.999
    assert h["flash_volume_mm3"][-1] > 10.0
    peak = np.max(h["force_N"])
    assert np.max(np.abs(h["force_top_N"] - h["force_bottom_N"])) <= 1e-7 * peak
    assert len(res.remeshes) >= 1
    volume = [r.volume_change for r in res.remeshes]
    assert np.sum(np.abs(volume)) < 1e-3


@pytest.mark.slow
@pytest.mark.parametrize("group", ["friction", "speed", "material"])
def test_gradients_with_two_dies_against_central_differences(group):
    """The forging work of a billet on a fixed anvil (3 x 6 q1p0, Coulomb 0.3, 30 %):
    its derivative along a random direction of each group (friction and speed act on both
    dies) against central differences (h = 1e-4, relative error <= 1e-5)."""
    pb = _two_die_problem()
    _, grad, _ = pb.value_and_grad(pb.start)
    exact, fd = directional_derivatives(pb, grad, group)
    assert abs(exact - fd) <= 1e-5 * abs(fd), (exact, fd)


@cache
def _two_die_problem():
    cfg = load_config(
        BILLET, ("billet.full_height=true", "mesh.nr=3", "mesh.nz=6", "time.dt_s=0.75")
    )
    return build_problem(build_scene(cfg), groups=("friction", "speed", "material"),
                         objective=ForgingWork(), single_program=True)  # fmt: skip
