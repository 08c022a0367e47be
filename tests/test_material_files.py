"""Bad material presets and material files are config errors: the command line prints one
line naming the key (``material.preset`` or ``--material``) and what is allowed, and exits
2, before anything is compiled; never a traceback."""

from pathlib import Path

import pytest

from jaxform.cli import main
from jaxform.config import ConfigError
from jaxform.materials.presets import available_presets, load_material

ROOT = Path(__file__).resolve().parents[1]
SEED = ROOT / "configs" / "upsetting_seed.toml"

ANAND = (ROOT / "jaxform" / "materials" / "data" / "al1100_673K.toml").read_text()


def _bad_inputs(tmp: Path) -> dict[str, tuple[str, str]]:
    """name -> (value of material.preset, a phrase the message must contain)."""

    def write(name, text):
        (tmp / name).write_bytes(text if isinstance(text, bytes) else text.encode())
        return str(tmp / name)

    (tmp / "folder.toml").mkdir()
    return {
        "unknown preset": ("steel", "no such preset"),
        "missing file": (str(tmp / "nowhere.toml"), "no such file"),
        "directory": (str(tmp / "folder.toml"), "is a directory"),
        "not TOML": (write("prose.toml", "this is not = = TOML\n"), "invalid TOML"),
        "binary": (write("binary.toml", bytes(range(128, 256))), "not a text (UTF-8) file"),
        "unknown law": (
            write("law.toml", ANAND.replace('"anand"', '"hookean"')),
            "law = 'hookean': must be one of ['anand', 'elastic', 'j2']",
        ),
        "no params": (write("noparams.toml", 'law = "j2"\n'), "needs a [params] table"),
        "missing parameter": (
            write("missing.toml", ANAND.replace("xi = 7.0\n", "")),
            "missing key(s) ['xi']",
        ),
        "unknown parameter": (
            write(
                "extra.toml", ANAND.replace("K_MPa = 66000.0\n", "K_MPa = 66000.0\nfoo_MPa = 1.0\n")
            ),
            "unknown key(s) ['foo_MPa']",
        ),
        "bad parameter": (
            write("negative.toml", ANAND.replace("s0_MPa = 29.7", "s0_MPa = -1")),
            "params.s0_MPa = -1.0: must lie in (0, inf)",
        ),
        "unknown thermal key": (
            write("thermal.toml", ANAND + "foo_W = 1.0\n"),
            "unknown key(s) ['foo_W'] in [thermal]",
        ),
        "bad thermal value": (
            write("cold.toml", ANAND.replace("density_kg_m3 = 2710.0", "density_kg_m3 = 0.0")),
            "thermal.density_kg_m3 = 0.0: must lie in (0, inf)",
        ),
        "non-number parameter": (
            write("text.toml", ANAND.replace("m = 0.23348", 'm = "x"')),
            "params.m = 'x': must be a number in (0, 1)",
        ),
    }


def test_every_bad_material_is_one_config_error_line(tmp_path, capsys):
    """Reference: the CLI contract (exit 2, one stderr line naming the key; for a missing
    preset or file, the allowed values: every preset name)."""
    for name, (value, phrase) in _bad_inputs(tmp_path).items():
        with pytest.raises(ConfigError, match="^material.preset = ") as info:
            load_material(value)
        assert phrase in str(info.value), (name, str(info.value))
        code = main(
            ["run", str(SEED), "--set", f"material.preset={value}", "--out", str(tmp_path / "out")]
        )
        err = capsys.readouterr().err
        assert code == 2, name
        assert err.count("\n") == 1 and "Traceback" not in err, (name, err)
        assert err.startswith(f"config error: material.preset = {value!r}: "), (name, err)
        assert phrase in err, (name, err)
        if name in ("unknown preset", "missing file", "directory"):
            assert all(p in err for p in available_presets()), err
    assert not (tmp_path / "out").exists()  # rejected before anything ran


def test_material_point_flag_names_itself(tmp_path, capsys):
    """The material-point command reports a bad --material the same way (exit 2)."""
    code = main(["material-point", "--material", "steel", "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert err.startswith("config error: --material = 'steel': no such preset")
