"""A blow's die as a spline in a process design (issue 39 part 3: the group
``<operation>.die_spline`` and a process's weighted sum of objectives of named operations).

One tiny process, shared (module-scoped): the seed billet on a 3 x 3 mesh, a flat blow whose
die is sampled at 6 radii, then a closed cone die with a flash land at r = 2.6 mm, also at 6
radii; each die's points in [0, 2.5] mm are a clamped cubic spline of 2 free control heights
(the ends pinned).  The objective is a configured weighted sum of the second blow's flash and
underfill and the first blow's press-capacity penalty, plus the splines' draft/fillet penalty.
References: central differences of the same run (h = 1e-4 along a unit direction), the
spline's own penalty by central differences where its rows are violated, the refusal line.
"""

from __future__ import annotations

import sys
from functools import cache
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest
from cli_harness import assert_refused
from fd_check import directional_derivatives

from jaxform.design.process_problem import build_process_problem, config_objective
from jaxform.errors import ConfigError
from jaxform.process import prepare, run_process
from jaxform.process_config import check_process_design, load_typed
from jaxform.process_gradients import ProcessPlan

sys.path.insert(0, str(Path(__file__).parent))
from test_process import TRIM_RADIUS, seed_document  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RADII = (0.0, 0.5, 1.0, 1.5, 2.5, 6.0)
FLAT = [[r, 3.75] for r in RADII]  # the seed billet's top (7.5 mm high, the upper half)
CONE = [[r, 3.38 + 0.05 * r] for r in RADII]
FIRST = {"kind": "forming", "name": "first", "die": {"reduction": 0.1, "profile_mm": FLAT}}
SECOND = {"kind": "forming", "name": "second", "travel_mm": 0.3,
          "die": {"profile_mm": CONE, "speed_mm_s": 0.15, "closed": True,
                  "part_radius_mm": TRIM_RADIUS}}  # fmt: skip
GROUPS = ("first.die_spline", "second.die_spline")
DESIGN = {
    "variables": [],
    "operation_variables": list(GROUPS),
    "die_spline_controls": 2,
    "die_spline_r1_mm": 2.5,
    "die_draft_deg": 30.0,
    "die_fillet_radius_min_mm": 5.0,
    "objective": "weighted_sum",
    "terms": ["flash_volume", "die_fill"],
    "operation_terms": ["first.press_capacity"],
    "term_weights": [1.0, 1.0, 1.0],
    "press_capacity_N": 200.0,  # below the first blow's peak: the term is active
}


def document(**design) -> dict:
    doc = seed_document([FIRST, SECOND])
    doc["friction"] = {"model": "shear", "m": 0.3}
    doc["design"] = DESIGN | design
    return doc


@cache
def problem():
    process = load_typed(document())
    check_process_design(process)
    result = run_process(process.operations, prepare(process.operations))
    plan = ProcessPlan.of(result)
    d = process.operations[0].config.design
    return build_process_problem(plan, GROUPS, config_objective(plan, d), single_program=True)


@cache
def start_gradient():
    pb = problem()
    return pb.value_and_grad(pb.start)


@pytest.mark.slow  # the tiny process's gradient programs: ~7 min cold on 2 busy cores
@pytest.mark.parametrize("group", GROUPS)
def test_die_spline_gradient_through_the_process(group):
    """dJ/du . du of each blow's spline controls against (J(u + h du) - J(u - h du)) / 2h,
    h = 1e-4 mm along a unit direction: relative error <= 1e-4 (the runs solve each step to
    Newton's tolerance; that noise over 2h bounds the quotient).  The flash and press terms
    are nonzero; the cone's cavity fills (underfill 0)."""
    pb = problem()
    val, grad, _ = start_gradient()
    report = pb.report(pb.start)
    for term in ("flash_volume", "first.press_capacity"):  # the cone's cavity fills: 0
        assert report[term] > 0.0, (term, report)
    assert abs(report["die_fill"]) <= 1e-9, report
    assert report["constraint_penalty"] == 0.0  # flat and shallow dies: no violated row
    assert abs(report["objective"] - float(val)) <= 1e-12 * abs(float(val))
    exact, fd = directional_derivatives(pb, grad, group)
    assert exact != 0.0
    assert abs(exact - fd) <= 1e-4 * abs(exact), (group, exact, fd)


@pytest.mark.slow  # shares the problem above
def test_die_spline_constraints_reach_the_process_objective():
    """The second die's spline at u = (0.6, -0.6) mm breaks the 5 mm fillet rows: the
    process group's penalty is its spline's (the same number), > 0, its gradient is
    central differences' (h = 1e-6, relative 1e-6), and the report lists its rows under
    the group's name."""
    pb = problem()
    g = next(g for g in pb.groups if g.name == "second.die_spline")
    u = jnp.asarray([0.6, -0.6])
    pen = float(g.penalty(u))
    assert pen > 0.0 and pen == float(g.inner.penalty(u))
    import jax

    grad = np.asarray(jax.grad(g.penalty)(u))
    du = np.array([0.6, 0.8])
    h = 1e-6
    fd = (float(g.penalty(u + h * du)) - float(g.penalty(u - h * du))) / (2 * h)
    assert abs(float(grad @ du) - fd) <= 1e-6 * abs(fd)
    rows = [r for r in pb.report(pb.start)["constraints"] if r["group"] == "second.die_spline"]
    assert {r["constraint"] for r in rows} >= {"draft_deg", "fillet_radius_mm"}


@pytest.mark.parametrize(
    "design, needle",
    [
        ({"die_spline_controls": 0}, "design.die_spline_controls >= 2"),
        ({"operation_variables": ["press.die_spline"]}, "no operation named 'press'"),
        ({"operation_terms": ["die_fill"]}, "'die_fill' names no operation"),
        ({"operation_terms": ["first.die_fill"]}, "die.closed = true"),
        ({"term_weights": [1.0]}, "as many design.term_weights"),
        ({"operation_terms": ["second.shape"]}, "a process's term is one of"),
    ],
)
def test_bad_die_spline_design_refused_in_one_line(tmp_path, design, needle):
    """A die_spline group or a weighted sum the process cannot serve: ConfigError naming
    the key, before anything runs; `jaxform design` exits 2 with that one line."""
    import tomli_w

    doc = document(**design)
    with pytest.raises(ConfigError, match=needle.replace("[", r"\[")) as err:
        check_process_design(load_typed(doc))
    assert "\n" not in str(err.value)
    path = tmp_path / "p.toml"
    path.write_bytes(tomli_w.dumps(doc).encode())
    assert_refused(["design", str(path), "--out", str(tmp_path / "o")], needle)


def test_two_stage_disk_design_config_is_accepted_and_starts_at_its_die():
    """experiments/two_stage_disk_design.toml passes the process's design check, and its
    blocker's die_spline group starts at the configured die (its flat web face): the
    spline's heights at u = 0 equal the profile's z at every sampled point (1e-12 mm; the
    replay's start design is the forward run's), 9 points sampled (r = 0 .. 4 mm), 4 free
    controls, no penalty at the start."""
    from jaxform.design.problem import build_group
    from jaxform.process import forming_scene

    process = load_typed(ROOT / "experiments" / "two_stage_disk_design.toml")
    check_process_design(process)
    ops = process.operations
    initial = prepare(ops)
    group = build_group(forming_scene(ops[0], initial, initial), "die_spline")
    pts = np.asarray(forming_scene(ops[0], initial, initial).inputs.die.members[0].points)
    u = group.initial()
    np.testing.assert_allclose(np.asarray(group.heights(u)), pts[group.points, 1], atol=1e-12)
    assert len(group.points) == 9 and len(group.free) == 4
    assert float(group.penalty(u)) == 0.0


@pytest.mark.slow  # one design iteration of the tiny process (its programs compiled above)
def test_design_command_on_a_process(tmp_path, capsys):
    """`jaxform design` of the tiny process (1 L-BFGS iteration): exit 0, the start
    design's terms on one line, design_report.csv with the start objective equal to the
    problem's (relative 1e-9), each term, each blow's peak force and the splines' rows;
    designed.toml (a valid process config) and die_profiles.csv / .png of both blows."""
    import csv

    import tomli_w

    from jaxform.cli import main

    path = tmp_path / "p.toml"
    path.write_bytes(tomli_w.dumps(document(iterations=1)).encode())
    out = tmp_path / "o"
    try:
        code = main(["design", str(path), "--out", str(out)])
    except SystemExit as exc:
        code = exc.code
    text = capsys.readouterr().out
    assert code == 0, text
    assert "start design: objective" in text
    with open(out / "design_report.csv", newline="") as fh:
        rows = {r["quantity"]: r for r in csv.DictReader(fh)}
    pb = problem()
    val, _, _ = start_gradient()
    assert abs(float(rows["objective"]["start"]) - float(val)) <= 1e-9 * abs(float(val))
    for k in ("flash_volume", "die_fill", "first.press_capacity", "first.peak_force_N",
              "second.peak_force_N", "second.die_spline.fillet_radius_mm"):  # fmt: skip
        assert k in rows, sorted(rows)
    capacity = pb.plan.stages[0].scene.settings.design.press_capacity_N
    assert float(rows["first.peak_force_N"]["start"]) > capacity
    assert (out / "design_history.csv").is_file() and (out / "config.toml").is_file()
    # the best design as a config, and each designed die before and after
    assert "jaxform run runs the design" in text
    assert "the best design's own forward run: objective" in text
    assert load_typed(out / "designed.toml").operations[1].name == "second"
    with open(out / "die_profiles.csv", newline="") as fh:
        ops = {r["operation"] for r in csv.DictReader(fh)}
    assert ops == {"first", "second"} and (out / "die_profiles.png").is_file()


@pytest.mark.slow  # the start evaluation of the tiny process (compiled above)
def test_a_design_stopped_after_its_first_evaluation_leaves_its_rows(tmp_path):
    """A process design interrupted right after its start evaluation (the progress
    callback raises, as Ctrl-C would): config.toml, design_history.csv (one row, the
    start objective to 1e-9 relative, the CSV's 10 digits) and designed.toml (the start
    design, a valid process config) are there already."""
    from jaxform.io import read_csv
    from jaxform.process_design import run_process_design

    process = load_typed(document(iterations=1))

    def stop(k, *row):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_process_design(process, tmp_path, progress=stop, problem=problem())
    h = read_csv(tmp_path / "design_history.csv")
    val, _, _ = start_gradient()
    rows = np.atleast_1d(h["objective"])
    assert rows.shape == (1,)
    assert abs(rows[0] - float(val)) <= 1e-9 * abs(float(val))  # the CSV's 10 digits
    assert load_typed(tmp_path / "designed.toml").operations[1].name == "second"
    assert (tmp_path / "config.toml").is_file()


@pytest.mark.slow  # shares the problem above
def test_die_spline_taylor_rate_through_the_process():
    """Taylor remainders of the second blow's die spline through the process (the first
    blow, then the cone die's): second-order rate >= 1.9."""
    from jaxform.design import taylor_test

    (row,) = taylor_test(problem(), groups=("second.die_spline",))
    assert row.group == "second.die_spline"
    assert row.min_rate >= 1.9, (row.rate1, row.r1)


@pytest.mark.parametrize(
    "name",
    ["two_stage_disk_flat_blocker.toml", "two_stage_disk_fixed_volume.toml"],
)
def test_flat_blocker_design_configs_start_flat_and_clear_of_the_billet(name):
    """The designs of the two-stage disk's blocker over its whole face from a flat
    blocker (the billet's volume a variable, or at 96 % of it) pass the process's design
    check; the die_spline group covers the whole face: 17 points sampled (r = 0 .. 8 mm
    every 0.5 mm), 6 free controls with free ends, every height the configured profile's
    at u = 0 (1e-12 mm: a flat face is a spline; the spline is fitted to the profile, so
    a profile with corners would not start as configured) and no penalty; and the die
    starts clear of the billet's top by more than the spline's bound, so that no design
    within the bounds stands in the billet at the start."""
    from jaxform.design.problem import build_group
    from jaxform.process import forming_scene

    process = load_typed(ROOT / "experiments" / name)
    check_process_design(process)
    ops = process.operations
    initial = prepare(ops)
    scene = forming_scene(ops[0], initial, initial)
    group = build_group(scene, "die_spline")
    u = group.initial()
    profile = np.asarray(ops[0].config.die.profile_mm, dtype=float)
    r, sampled = profile[group.points, 0], profile[group.points, 1]
    np.testing.assert_allclose(r, np.arange(17) * 0.5)
    np.testing.assert_allclose(np.asarray(group.heights(u)), sampled, atol=1e-12)
    assert len(group.points) == 17 and len(group.free) == 6
    assert float(group.penalty(u)) == 0.0
    coords = np.asarray(scene.mesh.coords)
    top, radius = float(coords[:, 1].max()), float(coords[:, 0].max())
    lowest = float(sampled[r <= radius + 1.0].min())
    bound = ops[0].config.design.die_spline_offset_max_mm
    assert lowest - top > bound
