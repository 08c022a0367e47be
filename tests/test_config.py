"""Tests of jaxform.config: loading, overrides, validation messages, round trip."""

import re
from pathlib import Path

import numpy as np
import pytest

from jaxform.config import (
    SCHEMA,
    ConfigError,
    check_gradient_run,
    describe_schema,
    dump_config,
    load_config,
)
from jaxform.dies import DieError, catmull_rom, check_profile

MINIMAL = {
    "billet": {"diameter_mm": 20, "height_mm": 30.0},
    "die": {"speed_mm_s": 1.0, "reduction": 0.5},
    "time": {"dt_s": 0.01},
}


def _with(section, key, value):
    """MINIMAL with one key set (a deep-enough copy)."""
    cfg = {s: dict(t) for s, t in MINIMAL.items()}
    cfg.setdefault(section, {})[key] = value
    return cfg


def test_minimal_fills_defaults():
    cfg = load_config(MINIMAL)
    # one workpiece section (the billet); no [load] (membrane scenes only)
    assert set(cfg) == set(SCHEMA) - {"ring", "block", "membrane", "load"}
    for section in cfg:
        assert set(cfg[section]) == set(SCHEMA[section])
    assert cfg["mesh"]["nr"] == 10 and cfg["mesh"]["element"] == "q1q1"
    assert cfg["solver"]["line_search"] is True
    assert cfg["billet"]["diameter_mm"] == 20.0
    assert isinstance(cfg["billet"]["diameter_mm"], float)  # int given for float converted
    assert "mesh" not in MINIMAL  # input not mutated


def test_overrides():
    cfg = load_config(
        MINIMAL,
        [
            "mesh.nr=20",
            "die.reduction=0.25",
            'mesh.element="q4"',
            "solver.linear=sparse",
            "output.plots=false",
        ],
    )
    assert cfg["mesh"]["nr"] == 20 and isinstance(cfg["mesh"]["nr"], int)
    assert cfg["die"]["reduction"] == 0.25
    assert cfg["mesh"]["element"] == "q4"
    assert cfg["solver"]["linear"] == "sparse"
    assert cfg["output"]["plots"] is False


def test_override_bare_string():
    assert load_config(MINIMAL, ["mesh.element=q1p0"])["mesh"]["element"] == "q1p0"


def test_unknown_section():
    with pytest.raises(ConfigError, match="unknown section 'bogus'"):
        load_config(_with("bogus", "x", 1))


def test_unknown_key():
    with pytest.raises(ConfigError, match=r"mesh\.foo") as exc:
        load_config(_with("mesh", "foo", 1))
    assert "nr" in str(exc.value) and "element" in str(exc.value)


def test_unknown_key_override():
    with pytest.raises(ConfigError, match=r"mesh\.foo"):
        load_config(MINIMAL, ["mesh.foo=1"])


@pytest.mark.parametrize(
    "section,key,value",
    [
        ("mesh", "nr", "ten"),
        ("mesh", "nr", 2.5),
        ("mesh", "nr", 3.0),
        ("mesh", "nr", True),
        ("billet", "height_mm", True),
        ("billet", "height_mm", "30"),
        ("solver", "line_search", 1),
        ("mesh", "element", 4),
    ],
)
def test_wrong_type(section, key, value):
    with pytest.raises(ConfigError, match=re.escape(f"{section}.{key}")):
        load_config(_with(section, key, value))


def test_negative_height():
    message = "billet.height_mm = -1.0: must lie in (0, 1000000]"
    with pytest.raises(ConfigError, match=re.escape(message)):
        load_config(_with("billet", "height_mm", -1.0))


@pytest.mark.parametrize("value", [1.0, 1.2, 0.0])
def test_reduction_out_of_range(value):
    msg = re.escape(f"die.reduction = {value!r}: must lie in (0, 1)")
    with pytest.raises(ConfigError, match=msg):
        load_config(_with("die", "reduction", value))


def test_zero_elements():
    with pytest.raises(ConfigError, match=re.escape("mesh.nr = 0: must lie in [1, 2000]")):
        load_config(_with("mesh", "nr", 0))


def test_bad_choice():
    with pytest.raises(ConfigError, match=r"mesh\.element = 'q9'") as exc:
        load_config(_with("mesh", "element", "q9"))
    for choice in ("q1q1", "q1p0", "q4"):
        assert choice in str(exc.value)


def test_missing_required():
    cfg = {s: dict(t) for s, t in MINIMAL.items()}
    del cfg["die"]["speed_mm_s"]
    with pytest.raises(ConfigError, match=r"missing required key die\.speed_mm_s"):
        load_config(cfg)


@pytest.mark.parametrize("text", ["mesh.nr", "nr=3", "mesh.=3", ".nr=3"])
def test_malformed_override(text):
    with pytest.raises(ConfigError, match=re.escape(f"malformed override {text!r}")):
        load_config(MINIMAL, [text])


def test_dump_load_round_trip(tmp_path):
    cfg = load_config(MINIMAL, ["mesh.nz=7", "output.fields=false"])
    dump_config(cfg, tmp_path / "scene.toml")
    assert load_config(tmp_path / "scene.toml") == cfg


def test_load_toml_file(tmp_path):
    path = tmp_path / "upset.toml"
    path.write_text(
        "[billet]\ndiameter_mm = 20\nheight_mm = 30\n"
        '[mesh]\nnr = 12\nelement = "q1p0"\n'
        "[die]\nspeed_mm_s = 1.0\nreduction = 0.6\n"
        "[time]\ndt_s = 0.05\n"
    )
    cfg = load_config(str(path), ["time.alpha=1"])
    assert cfg["mesh"]["nr"] == 12 and cfg["mesh"]["element"] == "q1p0"
    assert cfg["time"]["alpha"] == 1.0 and isinstance(cfg["time"]["alpha"], float)
    assert cfg["billet"]["height_mm"] == 30.0


def test_describe_schema_mentions_every_key():
    text = describe_schema()
    assert text.startswith("| key | type | default | allowed | meaning |")
    for section, fields in SCHEMA.items():
        for key in fields:
            assert f"`{section}.{key}`" in text


def test_ring_or_billet_exactly_one():
    ring = {
        "ring": {"outer_diameter_mm": 18.0, "inner_diameter_mm": 9.0, "height_mm": 6.0},
        **{k: v for k, v in MINIMAL.items() if k != "billet"},
    }
    assert load_config(ring)["ring"]["height_mm"] == 6.0
    with pytest.raises(ConfigError, match=r"exactly one workpiece"):
        load_config({**ring, "billet": MINIMAL["billet"]})
    with pytest.raises(ConfigError, match=r"ring.inner_diameter_mm"):
        load_config(ring, ["ring.inner_diameter_mm=20.0"])


def test_friction_and_die_keys_are_checked():
    with pytest.raises(ConfigError, match=r"friction.model = 'coulomb' needs friction.mu"):
        load_config(MINIMAL, ["friction.model=coulomb"])
    with pytest.raises(ConfigError, match=r"friction.m = 1.5: must lie in \[0, 1\]"):
        load_config(MINIMAL, ["friction.model=shear", "friction.m=1.5"])
    with pytest.raises(ConfigError, match=r"die.profile_mm"):
        load_config(MINIMAL, ["die.profile_mm=[[0.0, 1.0], [1.0]]"])
    with pytest.raises(ConfigError, match=r"die.path_time_s must increase"):
        load_config(
            MINIMAL, ["die.path_time_s=[0.0, 2.0, 1.0]", "die.path_travel_mm=[0.0, 1.0, 2.0]"]
        )
    cfg = load_config(MINIMAL, ["die.path_time_s=[0.0, 10.0]", "die.path_travel_mm=[0.0, 1.0]"])
    assert cfg["die"]["path_travel_mm"] == [0.0, 1.0]


# ---------------------------------------------------------------------------------------
# issue 22: nothing meaningless passes validation


@pytest.mark.parametrize(
    "key",
    [
        "billet.height_mm",
        "billet.diameter_mm",
        "time.dt_s",
        "die.speed_mm_s",
        "die.corner_radius_mm",
        "solver.rtol",
        "time.alpha",
        "solver.adjoint_memory_mb",
    ],
)
@pytest.mark.parametrize("value", ["inf", "-inf", "nan"])
def test_non_finite_numbers_are_refused(key, value):
    """inf passed the open ranges (0, inf) (an infinite height overflowed, an infinite dt
    ran no step, an infinite corner radius ran as if nothing were wrong)."""
    with pytest.raises(ConfigError, match=re.escape(f"{key} = {value}: must be a finite number")):
        load_config(MINIMAL, [f"{key}={value}"])


@pytest.mark.parametrize(
    "config, key",
    [
        ("configs/prandtl_punch.toml", "block.width_mm"),
        ("configs/cooks_membrane.toml", "load.force_y_N"),
        ("configs/cooks_membrane.toml", "load.ramp_time_s"),
    ],
)
def test_non_finite_numbers_are_refused_in_every_scene(config, key):
    with pytest.raises(ConfigError, match=re.escape(f"{key} = inf: must be a finite number")):
        load_config(config, [f"{key}=inf"])


@pytest.mark.parametrize(
    "override, message",
    [
        ("billet.height_mm=1e300", "billet.height_mm = 1e+300: must lie in (0, 1000000]"),
        ("die.corner_radius_mm=2e6", "die.corner_radius_mm = 2000000.0: must lie in (0, 1000000]"),
        ("die.speed_mm_s=1e7", "die.speed_mm_s = 10000000.0: must lie in (0, 1000000]"),
        ("die.profile_mm=[[0.0, 1.0], [1e300, 1.0]]", "die.profile_mm: entry 1e+300 mm"),
        ("design.bound_factor=1e300", "design.bound_factor = 1e+300: must lie in (1, 1000]"),
    ],
)
def test_huge_lengths_are_refused(override, message):
    """1 km is the largest length (a 1e300 mm diameter overflowed the contact scale)."""
    with pytest.raises(ConfigError, match=re.escape(message)):
        load_config(MINIMAL, [override])


@pytest.mark.parametrize(
    "overrides, message",
    [
        # reference: 0.5 x 30 mm / 1 mm/s = 15 s to the end; 15 s / 1e-6 s = 1.5e7 steps
        (
            ["time.dt_s=1e-6"],
            "time.dt_s = 1e-06: the run to 15 s (die.reduction x "
            "billet.height_mm / die.speed_mm_s) would take 1.5e+07 steps, at "
            "most 100000",
        ),
        (["die.speed_mm_s=1e-300"], "would take 1.5e+303 steps"),  # 1.5e301 s / 0.01 s
        (
            ["time.dt_s=1e300"],
            "time.dt_s = 1e+300: the run to 15 s (die.reduction x "
            "billet.height_mm / die.speed_mm_s) would take no step",
        ),
        (
            ["mesh.nr=1000", "mesh.nz=1000"],
            "mesh.nr x mesh.nz = 1000 x 1000 = 1000000 elements: at most 250000",
        ),
    ],
)
def test_run_size_caps(overrides, message):
    with pytest.raises(ConfigError, match=re.escape(message)):
        load_config(MINIMAL, overrides)


@pytest.mark.parametrize(
    "value, message", [("11", "must lie in [0, 10]"), ("1.5", "must be an int")]
)
def test_anderson_depth_is_a_small_count(value, message):
    with pytest.raises(ConfigError, match=re.escape(f"solver.anderson_depth = {value}: {message}")):
        load_config(MINIMAL, [f"solver.anderson_depth={value}"])


def test_step_cap_uses_the_path_table_to_the_stroke():
    """With a path table the run ends where the top die reaches reduction x H/2 = 7.5 mm
    (at t = 7.5 s on a table 0 -> 1e6 s): 7.5 s / 1e-4 s = 75 000 steps pass the cap,
    although the table runs 1e10 steps long; 1e-5 s steps (750 000) do not."""
    table = ["die.path_time_s=[0.0, 1e6]", "die.path_travel_mm=[0.0, 1e6]"]
    assert load_config(MINIMAL, table + ["time.dt_s=1e-4"])["time"]["dt_s"] == 1e-4
    with pytest.raises(ConfigError, match=re.escape("the run to 7.5 s (die.path_time_s")):
        load_config(MINIMAL, table + ["time.dt_s=1e-5"])


def test_material_start_factor_within_bounds():
    with pytest.raises(
        ConfigError,
        match=re.escape(
            "design.material_start_factor = 3.0: must lie in [1/design.bound_factor, "
            "design.bound_factor] = [0.5, 2]"
        ),
    ):
        load_config(MINIMAL, ["design.material_start_factor=3.0"])


def test_byte_order_mark_is_accepted(tmp_path):
    """A UTF-8 byte-order mark made a valid config 'invalid TOML'."""
    path = tmp_path / "bom.toml"
    path.write_bytes(b"\xef\xbb\xbf" + Path("configs/upsetting_seed.toml").read_bytes())
    assert load_config(path) == load_config("configs/upsetting_seed.toml")


@pytest.mark.parametrize(
    "kind, message",
    [
        ("missing", "cannot read the config"),
        ("folder", "is a folder"),
        ("binary", "not a UTF-8 text file"),
        ("empty", "empty config"),
    ],
)
def test_bad_config_files_name_the_file(kind, message, tmp_path):
    path = {"missing": tmp_path / "nope.toml", "folder": tmp_path}.get(kind, tmp_path / "c.toml")
    if kind == "binary":
        path.write_bytes(b"\x89PNG\r\n\x1a\n\x00\xff")
    elif kind == "empty":
        path.write_text("# only a comment\n")
    with pytest.raises(ConfigError, match=re.escape(f"{path}: {message}")):
        load_config(path)


@pytest.mark.parametrize(
    "overrides, groups, message",
    [
        (["mesh.rezone_quality=0.3"], None, "mesh.rezone_quality = 0.3: gradient runs need 0"),
        ([], [], "design.variables = []: name at least one design group"),
        ([], ["friction"], "'friction' needs friction.model = 'coulomb' or 'shear', not 'none'"),
        (
            ["die.path_time_s=[0.0, 100.0]", "die.path_travel_mm=[0.0, 10.0]"],
            ["speed"],
            "'speed' needs die.speed_mm_s",
        ),
        (["design.objective=die_fill"], None, "'die_fill' needs die.closed = true"),
        (["design.objective=force_misfit"], None, "'force_misfit' needs design.target_csv"),
        (
            ["design.objective=force_misfit", "design.target_csv=no/such.csv"],
            None,
            "design.target_csv = 'no/such.csv': no such file",
        ),
    ],
)
def test_gradient_run_checks(overrides, groups, message):
    cfg = load_config(MINIMAL, overrides)
    with pytest.raises(ConfigError, match=re.escape(message)):
        check_gradient_run(cfg, groups)


def test_gradient_run_checks_pass_a_valid_design():
    cfg = load_config("configs/preform_design.toml")
    check_gradient_run(cfg, cfg["design"]["variables"])  # raises nothing
    check_gradient_run(cfg, ["material", "friction", "speed", "preform", "nodes", "die"])


@pytest.mark.parametrize(
    "points, message",
    [
        ([[0.0, 1.0], [3.0, 2.0], [3.0, 0.5], [1.0, 3.0]], "segment 0-1 crosses segment 2-3"),
        (
            [[0.0, 1.0], [2.0, 1.0], [2.0, 2.0], [1.0, 2.0], [1.0, 1.0], [0.5, 0.0]],
            "segment 0-1 crosses segment 3-4",
        ),  # touches at (1, 1)
        ([[5.0, 1.0], [0.0, 1.0]], "lies on the left of the walk"),
        ([[1.0625, 13.0], [1.0625, 12.0], [0.0, 12.0]], "reverse their order"),  # Prandtl reversed
    ],
)
def test_die_profile_checks(points, message):
    with pytest.raises(DieError, match=re.escape(message)):
        check_profile(np.asarray(points), "die.profile_mm")


@pytest.mark.parametrize("config", ["configs/closed_die.toml", "configs/prandtl_punch.toml"])
def test_shipped_die_profiles_pass(config):
    pts = np.asarray(load_config(config)["die"]["profile_mm"])
    assert np.array_equal(check_profile(pts, "die.profile_mm"), pts)
    check_profile(catmull_rom(pts), "die.profile_mm (sampled spline)")


@pytest.mark.parametrize(
    "content, message",
    [
        (b"\x80\x81", "not a CSV text file"),  # binary: raised UnicodeDecodeError
        (b"a,b\n1,2\n", "needs a header with columns stroke_mm, force_N"),
        (b"stroke_mm,force_N\n", "needs a header"),  # no rows
        (
            b"stroke_mm,force_N\n0.5,nan\n",
            "line 2, column force_N = 'nan': must be a finite number",
        ),
        (b"stroke_mm,force_N\n0.5,\n", "line 2, column force_N = '': must be a finite number"),
    ],
)
def test_target_csv_checked_up_front(content, message, tmp_path):
    path = tmp_path / "target.csv"
    path.write_bytes(content)
    cfg = load_config(MINIMAL, ["design.objective=force_misfit", f"design.target_csv={path}"])
    message = f"design.target_csv = {str(path)!r}: {message}"
    with pytest.raises(ConfigError, match=re.escape(message)):
        check_gradient_run(cfg)


def test_target_csv_accepted(tmp_path):
    path = tmp_path / "target.csv"
    path.write_bytes(b"\xef\xbb\xbfstroke_mm,force_N\n0.0,0.0\n0.5,100.0\n")
    check_gradient_run(
        load_config(MINIMAL, ["design.objective=force_misfit", f"design.target_csv={path}"])
    )


@pytest.mark.parametrize("where", ["missing", "folder"])
def test_mesh_file_must_exist(where, tmp_path):
    path = tmp_path / "nope.msh" if where == "missing" else tmp_path
    with pytest.raises(ConfigError, match=re.escape(f"mesh.file = {str(path)!r}: no such file")):
        load_config(MINIMAL, [f"mesh.file={path}"])
