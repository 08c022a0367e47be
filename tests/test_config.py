"""Tests of jaxform.config: loading, overrides, validation messages, round trip."""

import re

import pytest

from jaxform.config import SCHEMA, ConfigError, describe_schema, dump_config, load_config

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
    cfg = load_config(MINIMAL, ["mesh.nr=20", "die.reduction=0.25",
                                'mesh.element="q4"', "solver.linear=sparse",
                                "output.plots=false"])
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


@pytest.mark.parametrize("section,key,value", [
    ("mesh", "nr", "ten"),
    ("mesh", "nr", 2.5),
    ("mesh", "nr", 3.0),
    ("mesh", "nr", True),
    ("billet", "height_mm", True),
    ("billet", "height_mm", "30"),
    ("solver", "line_search", 1),
    ("mesh", "element", 4),
])
def test_wrong_type(section, key, value):
    with pytest.raises(ConfigError, match=re.escape(f"{section}.{key}")):
        load_config(_with(section, key, value))


def test_negative_height():
    with pytest.raises(ConfigError, match=re.escape("billet.height_mm = -1.0: must lie in (0, 1000000]")):
        load_config(_with("billet", "height_mm", -1.0))


@pytest.mark.parametrize("value", [1.0, 1.2, 0.0])
def test_reduction_out_of_range(value):
    with pytest.raises(ConfigError, match=re.escape(f"die.reduction = {value!r}: must lie in (0, 1)")):
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
        "[mesh]\nnr = 12\nelement = \"q1p0\"\n"
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
    ring = {"ring": {"outer_diameter_mm": 18.0, "inner_diameter_mm": 9.0, "height_mm": 6.0},
            **{k: v for k, v in MINIMAL.items() if k != "billet"}}
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
        load_config(MINIMAL, ["die.path_time_s=[0.0, 2.0, 1.0]",
                              "die.path_travel_mm=[0.0, 1.0, 2.0]"])
    cfg = load_config(MINIMAL, ["die.path_time_s=[0.0, 10.0]", "die.path_travel_mm=[0.0, 1.0]"])
    assert cfg["die"]["path_travel_mm"] == [0.0, 1.0]
