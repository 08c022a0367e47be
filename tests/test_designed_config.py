"""The config of a design (jaxform.designed_config; issue 39: "the resolved config of
the final design, which `jaxform run` reproduces").

Reference: the forward run at the design itself.  A process at a design that moves every
group it offers (the billet's aspect and volume, the material, the heat, a die spline, a
die's points, friction, ram speed, a dwell's time and air) is run twice: as the design
runs it (`forward_plan(process, at=(problem, design))`, the groups applied to each
operation's inputs) and from the written designed.toml; the two agree in every step's time
(exactly), force (1e-9 relative), positions (1e-9 mm) and temperatures (1e-9 K).  A single
scene's designed config builds the inputs the design gives (1e-12).
"""

from __future__ import annotations

import copy
import sys
from functools import cache
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxform.design.process_problem import build_process_problem, process_objective
from jaxform.designed_config import designed_document, die_profiles, write_designed
from jaxform.process import prepare, run_process
from jaxform.process_config import load_typed, process_document
from jaxform.process_design import forward_plan
from jaxform.process_gradients import ProcessPlan

sys.path.insert(0, str(Path(__file__).parent))
from test_process import seed_document  # noqa: E402
from test_process_die_spline import FLAT  # noqa: E402
from test_process_gradients import AIR, CUT, SECOND, tiny_document  # noqa: E402

FIRST = {"kind": "forming", "name": "first", "die": {"reduction": 0.1, "profile_mm": FLAT}}
GROUPS = ("billet", "billet_volume", "material", "thermal", "first.die_spline",
          "first.friction", "second.die", "second.friction", "second.speed", "air.dwell",
          "air.thermal")  # fmt: skip
# toward the upper bound: the dies lift off the part (toward the lower bound they would
# start inside it, which the config's start check refuses)
UP = ("first.die_spline", "second.die")


@cache
def problem():
    doc = tiny_document((FIRST, AIR, SECOND, CUT))
    doc["design"] = {"die_spline_controls": 2, "die_spline_r1_mm": 2.5}
    process = load_typed(doc)
    plan = ProcessPlan.of(run_process(process.operations, prepare(process.operations)))
    return process, build_process_problem(plan, GROUPS, process_objective(plan, "peak_force"))


def design_of(pb):
    """5 % of the way from the start to a bound in every variable."""
    lo, hi = pb.bounds()
    return {k: v + 0.05 * ((hi if k in UP else lo)[k] - v) for k, v in pb.start.items()}


def _assert_same_runs(a_result, b_result, time_rtol: float = 0.0) -> None:
    """Two process runs alike: every step's time (to ``time_rtol``, default exactly),
    force (1e-9 of the peak), the largest temperature (1e-9 K) and the final positions
    (1e-9 mm)."""
    assert len(b_result.runs) == len(a_result.runs)
    for a, b in zip(a_result.runs, b_result.runs):
        ha, hb = a.result.history, b.result.history
        np.testing.assert_allclose(hb["time_s"], ha["time_s"], rtol=time_rtol, atol=0)
        peak = max(float(np.max(np.abs(ha["force_N"]))), 1.0)
        assert np.max(np.abs(hb["force_N"] - ha["force_N"])) <= 1e-9 * peak
        np.testing.assert_allclose(hb["max_temperature_K"], ha["max_temperature_K"], atol=1e-9)
        np.testing.assert_allclose(_positions(b), _positions(a), rtol=0, atol=1e-9)


@pytest.mark.parametrize("seed", [3, 11])
def test_a_random_design_reruns_from_its_config(tmp_path, seed):
    """A seeded random design (each variable a random 0 - 8 % of the way to a bound, the
    dies upward, the rest either way; a draw whose forward process is refused, a die
    over the incoming part, is drawn again): designed.toml reruns as the forward run at
    it (the step times to 1e-12: a speed or dwell factor written as dt and end rounds
    apart by an ulp)."""
    from jaxform.process import OperationRefused

    process, pb = problem()
    lo, hi = pb.bounds()
    rng = np.random.default_rng(seed)
    for _ in range(10):
        design = {}
        for k, v in pb.start.items():
            v = np.asarray(v)
            frac = rng.uniform(0.0, 0.08, v.shape)
            down = (rng.uniform(size=v.shape) < 0.5) & (k not in UP)
            design[k] = jnp.asarray(v + frac * (np.where(down, lo[k], hi[k]) - v))
        try:
            at_design, _ = forward_plan(process, at=(pb, design))
            break
        except OperationRefused:
            continue
    else:
        pytest.fail("none of 10 draws has a forward process")
    again = load_typed(write_designed(process, pb, design, tmp_path))
    rerun = run_process(again.operations, prepare(again.operations))
    _assert_same_runs(at_design, rerun, time_rtol=1e-12)


def _positions(run) -> np.ndarray:
    sc, x = run.result.final_scene, np.asarray(run.result.final_state.x)
    return np.asarray(sc.inputs.coords) + sc.model.layout.nodal(x)[:, :2]


def test_a_designed_process_config_runs_the_design(tmp_path):
    process, pb = problem()
    design = design_of(pb)
    at_design, _ = forward_plan(process, at=(pb, design))
    lines = []
    path = write_designed(process, pb, design, tmp_path, lines.append)
    assert path == tmp_path / "designed.toml" and "jaxform run runs the design" in lines[0]
    assert (tmp_path / "designed_material.toml").is_file()
    again = load_typed(path)
    rerun = run_process(again.operations, prepare(again.operations))
    assert len(rerun.runs) == 4
    _assert_same_runs(at_design, rerun)
    # the keys are the groups' closed forms: H = 7.5 e^a e^(v/3), D = 5 e^(-a/2) e^(v/3) mm
    designed = designed_document(process, pb, design)
    doc, material = designed.document, designed.material
    a, v = float(design["billet"][0]), float(design["billet_volume"][0])
    assert abs(doc["billet"]["height_mm"] - 7.5 * np.exp(a + v / 3)) <= 1e-12
    assert abs(doc["billet"]["diameter_mm"] - 5.0 * np.exp(-a / 2 + v / 3)) <= 1e-12
    second = next(t for t in doc["process"]["operation"] if t["name"] == "second")
    assert second["die"]["speed_mm_s"] < 0.15
    assert material["params"]["s0_MPa"] < 29.7
    # die_profiles.csv's rows: each moved die at the start and at the design, the latter
    # the written profile (exactly); the second die's points each 0.05 mm up (1e-12 mm)
    rows = die_profiles(pb, pb.start, design)
    assert {r["operation"] for r in rows} == {"first", "second"}
    first = next(t for t in doc["process"]["operation"] if t["name"] == "first")
    assert [r["z_designed_mm"] for r in rows if r["operation"] == "first"] == [
        z for _, z in first["die"]["profile_mm"]
    ]
    for r in (r for r in rows if r["operation"] == "second"):
        assert abs(r["z_designed_mm"] - r["z_start_mm"] - 0.05) <= 1e-12


def test_at_the_start_the_designed_process_is_the_configured_one():
    """At u = start the written keys restate the configured values: the same scenes'
    inputs (dies, coefficients, coordinates) at every operation's start (exactly)."""
    process, pb = problem()
    again = load_typed(designed_document(process, pb, pb.start).document)
    for k, stage in enumerate(pb.plan.stages):
        if not stage.stepped:
            continue
        op = again.operations[k]
        assert op.name == stage.name
    a = pb.plan.stages[0].scene.inputs
    from jaxform.process import forming_scene

    initial = prepare(again.operations)
    b = forming_scene(again.operations[0], initial, initial).inputs
    for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)):
        np.testing.assert_allclose(np.asarray(y), np.asarray(x), rtol=0, atol=1e-12)


@pytest.mark.parametrize("probe", [None, 0.5])
def test_a_designed_config_runs_with_the_design_s_solver(probe):
    """designed.toml's scenes are solved as the design's forward runs solve them
    (Scene.full_newton: full Newton, no probe of the first step), whatever the configured
    solver (modified Newton, a probe; also one in an operation's own [time]): the two
    runs converge each step by the same iterates, so their adaptive steps and remeshes
    fall alike (at a disk design on the edge of filling, modified Newton and the probe
    had moved the fill by 0.03 %)."""
    from jaxform.process import forming_scene

    process, pb = problem()
    doc = copy.deepcopy(process.document)
    doc.setdefault("solver", {})["newton"] = "modified"
    if probe is not None:
        doc["process"][0]["document"].setdefault("time", {})["first_step_probe"] = probe
    configured = load_typed(process_document(doc))
    again = load_typed(designed_document(configured, pb, pb.start).document)
    forming = [op for op in again.operations if op.forming]
    assert len(forming) == 2
    for op in forming:
        assert (op.config.solver.newton, op.config.time.first_step_probe) == ("newton", 0.0)
    initial = prepare(again.operations)
    scene = forming_scene(forming[0], initial, initial)
    ran = scene.full_newton()
    assert (scene.newton, scene.first_step_probe) == (ran.newton, ran.first_step_probe)


def test_a_single_scene_designed_config_builds_the_designed_inputs(tmp_path):
    """The seed scene (3 x 3) with its top die's points, friction, ram speed and
    material designed: the scene built from the designed document has the inputs the
    design gives (every leaf, 1e-12) and its time step scaled by the speed (1e-12)."""
    import jaxform

    doc = seed_document()
    doc["die"]["profile_mm"] = [[0.0, 3.75], [2.0, 3.75], [6.0, 3.75]]
    doc["friction"] = {"model": "coulomb", "mu": 0.2}
    scene = jaxform.build_scene(jaxform.load_config(doc))
    pb = jaxform.build_problem(scene, groups=("die", "friction", "speed", "material"))
    lo, hi = pb.bounds()
    design = {k: v + 0.1 * ((hi if k == "die" else lo)[k] - v) for k, v in pb.start.items()}
    cfg = load_typed(doc)
    path = write_designed(cfg, pb, design, tmp_path)
    assert (tmp_path / "designed_material.toml").is_file()
    rebuilt = jaxform.build_scene(jaxform.load_config(path))
    want, times = pb.run_inputs({k: jnp.asarray(v) for k, v in design.items()})
    for x, y in zip(jax.tree_util.tree_leaves(want), jax.tree_util.tree_leaves(rebuilt.inputs)):
        np.testing.assert_allclose(np.asarray(y), np.asarray(x), rtol=1e-12, atol=1e-12)
    slow = float(times[-1]) / float(pb.times[-1])
    assert abs(rebuilt.dt - scene.dt * slow) <= 1e-12 * scene.dt


def test_a_preform_design_is_written_as_its_mesh(tmp_path):
    """The nodes a preform group moves (two cosine modes of the seed billet's surface) are
    no config key: designed.toml names the designed first mesh, written as a mesh file
    (mesh.file), and the scene built from it has the design's coordinates (1e-12 mm) on
    the same elements."""
    import jaxform

    doc = seed_document()
    doc["design"] = {"preform_modes": 2}
    scene = jaxform.build_scene(jaxform.load_config(doc))
    pb = jaxform.build_problem(scene, groups=("preform",))
    design = {"preform": jnp.asarray([0.05, -0.03])}
    path = write_designed(load_typed(doc), pb, design, tmp_path)
    rebuilt = jaxform.build_scene(jaxform.load_config(path))
    want = np.asarray(pb.run_inputs(design)[0].coords)
    assert np.max(np.abs(want - np.asarray(scene.inputs.coords))) > 1e-3  # it moved them
    np.testing.assert_allclose(np.asarray(rebuilt.inputs.coords), want, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(rebuilt.mesh.elements, scene.mesh.elements)
