"""The config layer's promises beyond single keys: one end-time implementation for the
step count and the scene, a command that validates its config once, and the design
groups' and objectives' requirements as the one check of a gradient run."""

import re

import pytest

from jaxform.config import (
    SCHEMA,
    ConfigError,
    check_gradient_run,
    end_time,
    load_config,
    typed,
)
from jaxform.design import requirements

MINIMAL = {
    "billet": {"diameter_mm": 20, "height_mm": 30.0},
    "die": {"speed_mm_s": 1.0, "reduction": 0.5},
    "time": {"dt_s": 0.5},
    "mesh": {"nr": 2, "nz": 2},
}
# the dies close 15 mm (half of 30 mm) along both tables: 5 mm at 5 s, 18 mm at 20 s
FULL_HEIGHT_TABLES = [
    "billet.full_height=true",
    "die.path_time_s=[0.0, 20.0]",
    "die.path_travel_mm=[0.0, 12.0]",
    "bottom_die.path_time_s=[0.0, 5.0, 20.0]",
    "bottom_die.path_travel_mm=[0.0, 2.0, 6.0]",
]


@pytest.mark.parametrize(
    "overrides, t_end",
    [
        ([], 15.0),  # 0.5 x 30 mm / 1 mm/s
        (["die.path_time_s=[0.0, 4.0, 20.0]", "die.path_travel_mm=[0.0, 1.0, 9.0]"], 17.0),
        (["billet.full_height=true"], 15.0),
        (FULL_HEIGHT_TABLES, 5.0 + 10.0 * 15.0 / 13.0),
    ],
)
def test_step_count_and_scene_share_the_end_time(overrides, t_end):
    """Reference: the end time by hand (half height: the top die travels 7.5 mm, on the
    table 1 mm at 4 s, 9 mm at 20 s: 17 s; full height: the closure of both tables, 5 mm
    at 5 s, 18 mm at 20 s, reaches 15 mm at 5 + 10 x 15/13 s).  The config's step count
    and the scene's die motion take it from the same function."""
    from jaxform.scenes import build_scene

    cfg = typed(load_config(MINIMAL, overrides))
    assert end_time(cfg)[0] == pytest.approx(t_end, rel=1e-14)
    assert build_scene(cfg).t_end == pytest.approx(end_time(cfg)[0], rel=1e-15)


def test_a_table_that_stops_short_is_refused_when_the_scene_is_built():
    """The config cannot tell (a mesh file may set the height): no step-count check; the
    scene names the tables."""
    from jaxform.scenes import build_scene

    short = FULL_HEIGHT_TABLES[:-1] + ["bottom_die.path_travel_mm=[0.0, 0.5, 1.0]"]
    cfg = typed(load_config(MINIMAL, short))
    assert end_time(cfg) == (None, "")
    message = "die.path_travel_mm + bottom_die.path_travel_mm: the path ends at travel 13 mm"
    with pytest.raises(ConfigError, match=re.escape(message)):
        build_scene(cfg)


def test_jaxform_run_validates_its_config_once_and_enables_the_cache_once(monkeypatch, tmp_path):
    """Reference: counters on the cross-key check (every validation runs it once) and on
    the cache's switch; the run stops where the scene would be built."""
    import jaxform.cache
    from jaxform import cli, driver
    from jaxform.config import loading

    calls = {"validations": 0, "cache": 0}
    check = loading.check_document

    def counted_check(*args):
        calls["validations"] += 1
        return check(*args)

    def counted_cache(*args):
        calls["cache"] += 1

    class Built(Exception):
        pass

    def build_scene(cfg):
        raise Built

    monkeypatch.setattr(loading, "check_document", counted_check)
    monkeypatch.setattr(jaxform.cache, "enable_compilation_cache", counted_cache)
    monkeypatch.setattr(driver, "enable_compilation_cache", counted_cache)
    monkeypatch.setattr(driver, "build_scene", build_scene)
    with pytest.raises(Built):
        cli.main(["run", "configs/upsetting_seed.toml", "--out", str(tmp_path)])
    assert calls == {"validations": 1, "cache": 1}


def test_the_config_offers_the_declared_groups_and_objectives():
    assert SCHEMA["design"]["variables"].choices == tuple(requirements.GROUPS)
    assert SCHEMA["design"]["objective"].choices == tuple(requirements.OBJECTIVES)
    assert all(spec.doc for spec in requirements.GROUPS.values())
    assert all(spec.doc for spec in requirements.OBJECTIVES.values())


@pytest.mark.parametrize(
    "overrides, group, message",
    [
        (["thermal.model=coupled", "thermal.htc_die_W_m2K=0"], "thermal",
         "'thermal' needs thermal.model = 'coupled' and thermal.htc_die_W_m2K > 0"),
        (["mesh.file=configs/../README.md"], "preform",
         "'preform' needs a [billet] scene on the structured mesh"),
        (["press.model=crank"], "speed", "'speed' needs press.model = 'speed'"),
        (["friction.model=sticking"], "friction",
         "'friction' needs friction.model = 'coulomb' or 'shear', not 'sticking'"),
    ],
)  # fmt: skip
def test_each_group_declares_what_it_needs(overrides, group, message):
    """The first unmet requirement of the group, in the one line of the refusal; the
    same function decides whether the group is offered (jaxform taylor-test's default)."""
    cfg = typed(load_config(MINIMAL, overrides))
    assert requirements.unmet_group(cfg, group) is not None
    with pytest.raises(ConfigError, match=re.escape(f"design.variables = ['{group}']: {message}")):
        check_gradient_run(cfg, [group])
    assert requirements.unmet_group(typed(load_config(MINIMAL)), "nodes") is None


@pytest.mark.parametrize(
    "objective, overrides, message",
    [
        ("side_straightness", None, "needs a [billet] or [ring] scene"),
        ("temperature_misfit", [], "needs thermal.model = 'coupled'"),
        ("wear_depth", [], "needs wear.on = true"),
        ("shape_target", [], "needs design.target_csv"),
    ],
)
def test_each_objective_declares_what_it_needs(objective, overrides, message):
    if overrides is None:  # a block: no free side
        doc = load_config("configs/prandtl_punch.toml", [f"design.objective={objective}"])
    else:
        doc = load_config(MINIMAL, [*overrides, f"design.objective={objective}"])
    with pytest.raises(ConfigError, match=re.escape(f"design.objective = '{objective}' {message}")):
        check_gradient_run(doc)
