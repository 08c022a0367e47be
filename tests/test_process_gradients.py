"""Exact gradients through a multi-stage process (issue 39, part 2: jaxform.process_gradients,
jaxform.design.process_problem).  Each test names its reference and tolerance.

The fast tests share one tiny process (module-scoped): the seed billet on a 3 x 3 mesh with
coupled heat and shear friction, a first blow (4 steps), 1 s in air (4 heat steps), a
second blow with a closed cone die and a flash land at r = 2.6 mm (2 steps), a trim at
2.6 mm.  References: the forward process run itself (the replay takes its steps), central
finite differences of the same differentiable run (h = 1e-4 along a unit direction,
relative error <= 1e-5), Taylor remainders (rate >= 1.9), closed forms for the volumes.
The slow tests take the shipped configs/two_stage_disk.toml (one forward run ~60 s warm).
"""

from __future__ import annotations

import sys
from dataclasses import replace
from functools import cache
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest
from cli_harness import assert_refused
from fd_check import directional_derivatives

from jaxform.design import taylor_test
from jaxform.design.objectives import FlashVolume, part_cavity_volume, polygon_measure_beyond
from jaxform.design.parametrize import BilletAspect, workpiece_volume
from jaxform.design.process_problem import (
    WeightedSum,
    build_process_problem,
    process_objective,
)
from jaxform.errors import ConfigError
from jaxform.postprocess import material_beyond
from jaxform.process import prepare, run_process
from jaxform.process_config import check_process_design, load_typed
from jaxform.process_gradients import ProcessPlan, SetTemperature, process_trajectory

sys.path.insert(0, str(Path(__file__).parent))
from test_process import CONE, FIRST, TRIM_RADIUS, seed_document  # noqa: E402

# every test here replays whole processes (dozens of compiled programs, 145 s on an idle
# 2-core machine): the slow suite (python -m pytest -m slow)
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]
SECOND = {"kind": "forming", "name": "second", "travel_mm": 0.3,
          "die": {"profile_mm": CONE, "speed_mm_s": 0.15, "closed": True,
                  "part_radius_mm": TRIM_RADIUS}}  # fmt: skip
AIR = {"kind": "dwell", "name": "air", "time_s": 1.0, "dt_s": 0.25, "htc_air_W_m2K": 2000.0}
CUT = {"kind": "trim", "name": "cut", "radius_mm": TRIM_RADIUS}
# every group the tiny process offers: the process's and each operation's
GROUPS = ("billet", "material", "thermal", "first.die", "first.friction", "second.die",
          "second.friction", "second.speed", "air.dwell", "air.thermal")  # fmt: skip


def tiny_document(operations=(FIRST, AIR, SECOND, CUT)) -> dict:
    doc = seed_document(list(operations))
    doc["thermal"] = {"model": "coupled", "die_temperature_K": 573.0}
    doc["friction"] = {"model": "shear", "m": 0.3}
    return doc


@cache
def forward():
    process = load_typed(tiny_document())
    result = run_process(process.operations, prepare(process.operations))
    return process, result, ProcessPlan.of(result)


def objective(plan):
    """The first blow's peak force, the flash of the second, the part's mean temperature
    after the trim: outputs of three operations in one number."""
    return WeightedSum((
        (1e-3, process_objective(plan, "peak_force", "first")),
        (1.0, process_objective(plan, "flash_volume", "second")),
        (0.01, process_objective(plan, "mean_temperature", "cut")),
    ))  # fmt: skip


@cache
def problem():
    _, _, plan = forward()
    return build_process_problem(plan, GROUPS, objective(plan), single_program=True)


@cache
def start_gradient():
    pb = problem()
    return pb.value_and_grad(pb.start)


def assert_replays(result, ptraj):
    """Each operation of ``ptraj`` is that of the forward process run ``result``: its last
    step's time (1e-12 relative), its forces (1e-7 of the peak) and final positions
    (1e-9 mm)."""
    for run, traj in zip(result.runs, ptraj.operations):
        h = run.result.history
        np.testing.assert_allclose(np.asarray(traj.time_s)[-1], h["time_s"][-1], rtol=1e-12)
        f = np.asarray(traj.force_N)
        assert np.max(np.abs(f - h["force_N"])) <= 1e-7 * max(np.max(np.abs(f)), 1.0)
        sc = run.result.final_scene
        lay = sc.model.layout
        pos = np.asarray(sc.inputs.coords) + lay.nodal(np.asarray(run.result.final_state.x))[:, :2]
        np.testing.assert_allclose(np.asarray(traj.positions), pos, rtol=0, atol=1e-9)


def test_the_replay_takes_the_forward_runs_steps_and_maps():
    """Each operation of the differentiable run equals the forward process run: the same
    steps (time 1e-12), forces and final positions to the Newton tolerance (1e-7 of the
    peak, 1e-9 mm), the dwell's temperatures (1e-6 K); the trim is the forward run's
    StateMap, the others' entry maps its Carry."""
    _, result, plan = forward()
    kinds = [type(s.entry).__name__ for s in plan.stages]
    assert kinds == ["NoneType", "Carry", "Carry", "StateMap"]
    assert [len(s.segments) for s in plan.stages] == [1, 1, 1, 0]
    ptraj = process_trajectory(plan)
    assert_replays(result, ptraj)
    air = result.runs[1].result.history
    temps = np.asarray(ptraj.operations[1].temperature_K)  # (rows, nodes)
    np.testing.assert_allclose(temps.min(axis=1), air["min_temperature_K"], rtol=0, atol=1e-6)
    np.testing.assert_allclose(temps.max(axis=1), air["max_temperature_K"], rtol=0, atol=1e-6)
    assert air["mean_temperature_K"][-1] < air["mean_temperature_K"][0] - 1.0  # it cooled
    assert np.all(np.asarray(ptraj.codes) == 0)


@pytest.mark.parametrize("group", GROUPS)
def test_process_gradient_against_central_differences(group):
    """dJ/du . du of every group (the billet's aspect, the material, the process's and
    the dwell's heat, each blow's die points, friction and speed, the dwell's time)
    against (J(u + h du) - J(u - h du)) / 2h, h = 1e-4 along a unit direction: relative
    error <= 1e-4 (measured 1e-9 .. 4e-5: the runs solve each step to Newton's tolerance,
    whose noise over 2h bounds the difference quotient of the smallest derivatives)."""
    pb = problem()
    _, grad, _ = start_gradient()
    exact, fd = directional_derivatives(pb, grad, group)
    assert exact != 0.0
    assert abs(exact - fd) <= 1e-4 * abs(exact), (group, exact, fd)


def test_a_plan_made_at_a_design_replays_that_designs_forward_run():
    """The forward process run at a design that moves every group but the first blow's die
    (on the billet) 5 % of the way to a bound (the billet, the material, the heat, the
    second blow's die, friction and its speed,
    the dwell's time) and its plan, which keeps each operation's inputs and times as
    configured: the problem's groups applied to them replay that run (steps 1e-12
    relative, forces 1e-7 of the peak, positions 1e-9 mm), which differs from the start
    design's (the first blow's peak force by > 0.1 %).  A problem whose replay fails
    (made to) runs the forward process at the design and evaluates it on that plan:
    the same value (1e-12)."""
    from dataclasses import replace

    from jaxform.gradients import GradientRunError
    from jaxform.process_design import Replanning, forward_plan

    process, start_result, _ = forward()
    pb = problem()
    lo, hi = pb.bounds()
    # toward each lower bound (a shorter billet, less friction, a slower blow, a shorter
    # dwell), the second blow's die toward its upper one, the first's where it starts (on
    # the billet): each die starts clear of the part it receives (lower, the first would
    # start inside the billet, which a design rejects as the config check would)
    design = {k: v + 0.05 * ((hi if k == "second.die" else lo)[k] - v) for k, v in pb.start.items()}
    design["first.die"] = pb.start["first.die"]
    result, plan = forward_plan(process, at=(pb, design))
    at = replace(pb, plan=plan, objective=objective(plan))
    assert_replays(result, process_trajectory(plan, *at.run_inputs(design)))
    peak, peak0 = (np.max(r.runs[0].result.history["force_N"]) for r in (result, start_result))
    assert abs(peak / peak0 - 1.0) > 1e-3, (peak, peak0)

    class Fails:
        def value(self, design):
            raise GradientRunError("made to fail")

    replanning = Replanning(process, pb, objective_of=objective)
    replanning.current = Fails()
    value, _ = replanning.value(design)
    assert replanning.replans == 1
    assert float(value) == pytest.approx(float(at.value(design)[0]), rel=1e-12)


@pytest.mark.parametrize("level", ["all", "compiled"])
def test_a_crowded_replay_lets_its_programs_go_and_keeps_the_gradient(monkeypatch, level):
    """Reference: the shared start gradient (the whole replay as one program).  The replay
    mesh by mesh (separate programs, as a design runs it) with every compiled program let
    go before each mesh and each mesh's reverse pass (both memory-map shares set to 0, as
    in a process near vm.max_map_count; ``compiled``: only the compiled executables,
    their traces kept): at least one release per mesh each way, and the same objective
    and gradient to 1e-9 of each group's largest component."""
    import jax

    from jaxform import program_store

    released = []
    real = {"all": program_store.release_programs, "compiled": program_store.release_compiled}
    name = {"all": "release_programs", "compiled": "release_compiled"}[level]
    monkeypatch.setattr(program_store, "MAP_SHARE", 0.0)
    monkeypatch.setattr(program_store, "CLEAR_SHARE", 0.0)
    monkeypatch.setattr(program_store, name, lambda: (released.append(1), real[level]())[1])
    if level == "compiled":
        monkeypatch.setattr(program_store, "release_programs", lambda: None)
    _, _, plan = forward()
    pb = build_process_problem(plan, GROUPS, objective(plan))
    val, grad, _ = pb.value_and_grad(pb.start)
    ref_val, ref_grad, _ = start_gradient()
    meshes = sum(len(s.segments) for s in plan.stages)
    assert len(released) >= 2 * meshes, (len(released), meshes)
    assert abs(float(val) - float(ref_val)) <= 1e-9 * abs(float(ref_val))
    for a, b in zip(jax.tree_util.tree_leaves(grad), jax.tree_util.tree_leaves(ref_grad)):
        a, b = np.asarray(a), np.asarray(b)
        assert np.max(np.abs(a - b)) <= 1e-9 * max(np.max(np.abs(b)), 1e-300)


def test_process_taylor_rates():
    """Taylor remainders of two groups that act on different operations (the second
    blow's die, the billet's aspect before the first): second-order rates >= 1.9."""
    rows = taylor_test(problem(), groups=("second.die", "billet"))
    assert {r.group for r in rows} == {"second.die", "billet"}
    for r in rows:
        assert r.min_rate >= 1.9, (r.group, r.rate1)


def test_flash_volume_is_the_clipped_volume_and_smooth():
    """polygon_measure_beyond equals the host's clipped-polygon volume (postprocess.material_beyond,
    Sutherland-Hodgman) on the second blow's deformed mesh to 1e-12 relative, axisymmetric
    and plane; its derivative in the nodal positions equals central differences (1e-6)."""
    _, result, plan = forward()
    sc = result.runs[2].result.final_scene
    pos = np.asarray(process_trajectory(plan).operations[2].positions)
    quads = pos[np.asarray(sc.mesh.elements)]
    for radius in (1.0, 2.2, 2.6):
        ref = material_beyond(sc, pos, radius)
        got = float(jnp.sum(polygon_measure_beyond(quads, radius, True)))
        assert abs(got - ref) <= 1e-12 * ref, (radius, got, ref)
        plane = replace(sc, model=replace(sc.model, formulation=replace(
            sc.model.formulation, axisymmetric=False)))  # fmt: skip
        ref_p = material_beyond(plane, pos, radius)
        got_p = float(jnp.sum(polygon_measure_beyond(quads, radius, False)))
        assert abs(got_p - ref_p) <= 1e-12 * ref_p
    flash = FlashVolume(np.asarray(sc.mesh.elements), 2.2, True)
    import jax

    traj = process_trajectory(plan).operations[2]
    g = jax.grad(lambda p: flash(replace(traj, positions=p), None))(jnp.asarray(pos))
    du = np.random.default_rng(3).standard_normal(pos.shape)
    h = 1e-6
    fd = (flash(replace(traj, positions=pos + h * du), None)
          - flash(replace(traj, positions=pos - h * du), None)) / (2 * h)  # fmt: skip
    assert abs(float(fd) - float(np.sum(np.asarray(g) * du))) <= 1e-6 * abs(float(fd))


def test_cavity_of_a_flat_closed_die_is_a_cylinder():
    """A flat closed die at z = 2 mm moved down by 0.5 mm, the part inside r <= 3 mm:
    pi R^2 h = pi 9 1.5 mm^3 (1e-12); plane strain R h = 4.5 mm^2."""
    pts = jnp.asarray([[0.0, 2.0], [5.0, 2.0]])
    assert abs(float(part_cavity_volume(pts, 0.5, 3.0, True)) - np.pi * 9 * 1.5) < 1e-12
    assert abs(float(part_cavity_volume(pts, 0.5, 3.0, False)) - 4.5) < 1e-12


def test_billet_aspect_keeps_the_volume_and_the_die_on_the_top():
    """The billet 10 % taller at fixed volume: its mesh's volume unchanged (1e-12), its
    top 1.1 times higher and the top die lifted by the same 0.1 H (1e-12)."""
    _, _, plan = forward()
    inputs = plan.stages[0].scene.inputs
    elements = np.asarray(plan.stages[0].scene.mesh.elements)
    top = float(np.max(np.asarray(inputs.coords)[:, 1]))
    group = BilletAspect(True)
    moved, _ = group.apply(jnp.log(jnp.asarray([1.1])), inputs, jnp.zeros(1))
    v0 = float(workpiece_volume(inputs.coords, elements, True))
    assert abs(float(workpiece_volume(moved.coords, elements, True)) - v0) <= 1e-12 * v0
    assert abs(float(jnp.max(moved.coords[:, 1])) - 1.1 * top) <= 1e-12 * top
    lift = moved.die.members[0].points[:, 1] - inputs.die.members[0].points[:, 1]
    np.testing.assert_allclose(np.asarray(lift), 0.1 * top, rtol=1e-12)


def test_set_temperature_map():
    """A reheat to a set temperature as a traced map: every node at 700 K (1e-9 K)."""
    _, result, _ = forward()
    sc = result.runs[0].result.final_scene
    lay = sc.model.layout
    state = result.runs[0].result.final_state
    th = sc.inputs.thermal
    new, _ = SetTemperature(lay, 700.0).apply(state, sc.inputs.coords, th)
    temps = np.asarray(lay.nodal(new.x)[:, lay.temperature_column]) + float(th.billet_temperature_K)
    np.testing.assert_allclose(temps, 700.0, rtol=0, atol=1e-9)


@pytest.mark.parametrize(
    "design, groups, needle",
    [
        ({"operation": "press"}, None, "design.operation = 'press': no operation"),
        ({"operation_variables": ["air.die"]}, None, "is no forming operation"),
        ({"operation_variables": ["first.dwell"]}, None, "is no dwell or furnace"),
        ({"operation_variables": ["blocker.die"]}, None, "no operation named 'blocker'"),
        ({"operation_variables": ["die"]}, None, "'die' names no operation"),
        ({"operation": "air", "variables": ["die"]}, None, "is no forming operation"),
        ({"operation_variables": ["first.shape"]}, None, "is not a process's design group"),
        ({"objective": "side_straightness"}, None, "a process's objective is one of"),
        ({"objective": "flash_volume", "objective_operation": "first"}, None,
         "die.part_radius_mm > 0"),
        ({"objective": "flash_volume", "objective_operation": "air"}, None,
         "a forming operation"),
        ({}, ["second.nodes"], "is not a process's design group"),
    ],
)  # fmt: skip
def test_bad_process_design_refused_in_one_line(tmp_path, design, groups, needle):
    """A process's [design] that cannot be served: ConfigError naming the key, before
    anything compiles (the CLI: exit 2, one line)."""
    import tomli_w

    doc = tiny_document()
    doc["design"] = {"variables": ["die"], "objective": "flash_volume", **design}
    process = load_typed(doc)
    with pytest.raises(ConfigError, match=needle.replace("(", r"\(").replace(")", r"\)")):
        check_process_design(process, groups, "--groups" if groups else "design.variables")
    path = tmp_path / "p.toml"
    path.write_bytes(tomli_w.dumps(doc).encode())
    argv = ["taylor-test", str(path)] + (["--groups", *groups] if groups else [])
    assert_refused(argv, needle.split(":")[0] if "=" in needle else needle)


def test_one_scene_refuses_a_design_operation():
    """design.operation in a config without a process: refused in one line."""
    doc = seed_document()
    doc["design"] = {"operation": "finisher"}
    from jaxform.config import check_gradient_run, load_config

    with pytest.raises(ConfigError, match="design.operation = 'finisher'"):
        check_gradient_run(load_config(doc))


# ----------------------------------------------------------------------------------
# the shipped two-stage disk (slow: a forward run ~60 s warm, a gradient ~2-3 times that)

DISK_GROUPS = ("blocker.die", "blocker.friction", "finisher.friction", "blocker.speed",
               "billet", "thermal", "transfer.dwell")  # fmt: skip


@cache
def disk_problem():
    process = load_typed(ROOT / "configs" / "two_stage_disk.toml")
    result = run_process(process.operations, prepare(process.operations))
    plan = ProcessPlan.of(result)
    obj = WeightedSum((
        (1.0, process_objective(plan, "die_fill", "finisher")),
        (1e-2, process_objective(plan, "flash_volume", "finisher")),
        (1e-5, process_objective(plan, "peak_force", "blocker")),
    ))  # fmt: skip
    return build_process_problem(plan, DISK_GROUPS, obj)


@pytest.mark.slow
def test_two_stage_disk_gradients_against_central_differences():
    """Every group on the shipped scene: dJ/du . du against central differences
    (h = 1e-5, unit direction): relative error <= 1e-4 (the runs solve to the Newton
    tolerance through 79 steps and 9 remeshes: ~1e-10 / h).  Not h = 1e-4: along
    blocker.friction (m = 0.3) that step crosses a kink of the replay (central
    difference 0.00940 against 0.00658), where h = 1e-5 and 1e-6 give 0.0065808 both
    ways (forward and backward differences within 1e-3 of each other)."""
    pb = disk_problem()
    _, grad, _ = pb.value_and_grad(pb.start)
    for group in DISK_GROUPS:
        exact, fd = directional_derivatives(pb, grad, group, h=1e-5)
        print(f"{group}: exact {exact:.8g}, central difference {fd:.8g}")  # the docs' table
        assert abs(exact - fd) <= 1e-4 * abs(exact), (group, exact, fd)


@pytest.mark.slow
def test_two_stage_disk_taylor_rates():
    """Taylor remainders of every group on the shipped scene: rates >= 1.9."""
    rows = taylor_test(disk_problem())
    for r in rows:
        assert r.min_rate >= 1.9, (r.group, r.rate1)


def test_taylor_test_command_on_a_process(tmp_path, capsys):
    """`jaxform taylor-test` of a process config (the tiny process, design.variables =
    [] and design.operation_variables = [second.die], objective the second blow's flash):
    a line as each operation's forward run starts, each evaluation, the table and
    min_rate >= 1.9 (exit 0)."""
    import tomli_w

    from jaxform.cli import main

    doc = tiny_document()
    doc["design"] = {"variables": [], "operation_variables": ["second.die"],
                     "objective": "flash_volume"}  # fmt: skip
    path = tmp_path / "p.toml"
    path.write_bytes(tomli_w.dumps(doc).encode())
    try:
        code = main(["taylor-test", str(path)])
    except SystemExit as exc:
        code = exc.code
    out = capsys.readouterr().out
    assert code == 0, out
    assert "forward run of process.operation[1] (first)" in out
    assert "forward run of process.operation[3] (second)" in out
    assert "second.die: h = " in out
    assert float(out.split("min_rate=")[1].split()[0]) >= 1.9


def test_objectives_of_a_named_operation():
    """A single-scene objective on one operation (OnOperation): the press-capacity
    penalty of the second blow at half its peak force is weight x ((F - C) / C)^2 =
    1 (1e-12); the lap penalty of the mesh it ends on is finite and >= 0; an unknown
    objective or operation is refused."""
    from jaxform.design import objectives as obj
    from jaxform.design.process_problem import OnOperation

    _, _, plan = forward()
    ptraj = process_trajectory(plan)
    peak = float(jnp.max(ptraj.operations[2].force_N))
    cap = OnOperation(obj.PressCapacity(0.5 * peak, 1.0), 2)
    assert abs(float(cap(ptraj, plan.inputs())) - 1.0) < 1e-12
    lap = process_objective(plan, "lap", "second")
    value = float(lap(ptraj, plan.inputs()))
    assert np.isfinite(value) and value >= 0.0
    with pytest.raises(ValueError, match="must be one of"):
        process_objective(plan, "side_straightness")
    with pytest.raises(ValueError, match="no operation named 'finisher'"):
        process_objective(plan, "peak_force", "finisher")
