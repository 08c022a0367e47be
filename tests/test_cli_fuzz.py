"""Property-based fuzz of the command line with bad input (issue 22).

Hypothesis draws a shipped config, a subcommand, a key of the config and a value that is
wrong for it (wrong type, NaN, +-inf, huge, empty, negative where the range is positive,
an unknown key), or a bad config file (missing, a folder, binary, empty).  The CLI runs
in-process with every entry point that would compile replaced by a stub that fails the
test, so the refusal must come before compilation.  Reference: the project's rule for bad
input -- exit status 2, exactly one line on stderr naming the key, flag or file, no
traceback.  No tolerance: each property is exact.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import pytest
from cli_harness import Reached, assert_refused, run_cli
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxform.config import SCHEMA
from jaxform.process_config import load_document

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = sorted((ROOT / "configs").glob("*.toml"))
COMMANDS = ("run", "design", "taylor-test")


def base_argv(command: str, path: Path, out: Path) -> list[str]:
    argv = [command, str(path)] + (["--out", str(out)] if command != "taylor-test" else [])
    raw = tomllib.loads(path.read_bytes().decode("utf-8-sig"))
    if command != "run" and raw.get("mesh", {}).get("rezone_quality", 0) > 0:
        argv += ["--set", "mesh.rezone_quality=0"]  # gradient runs refuse rezoning
    if command != "run" and raw.get("remesh"):  # and remeshing
        argv += ["--set", "remesh.quality_below=0", "--set", "remesh.every_steps=0"]
    return argv


def _toml(v) -> str:
    if isinstance(v, float) and not math.isfinite(v):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf")
    if isinstance(v, str):
        return '"' + v + '"'
    if isinstance(v, list):
        return "[" + ", ".join(_toml(x) for x in v) + "]"
    return repr(v)


def bad_values(section: str, key: str):
    """A strategy of values that every config must refuse for ``section.key``."""
    f = SCHEMA[section][key]
    nonfinite = st.sampled_from([math.nan, math.inf, -math.inf])
    text = st.text(alphabet="abcxyz", min_size=0, max_size=6)
    if f.kind in ("float", "int"):
        options = [nonfinite, text, st.lists(st.floats(0, 1), min_size=1, max_size=2)]
        if f.low is not None and f.low >= 0:
            options.append(st.floats(-1e300, -1e-300))
        if f.high is not None:
            options.append(
                st.floats(f.high * 2 + 1, 1e300)
                if f.kind == "float"
                else st.integers(f.high + 1, 10**15)
            )
        if f.kind == "int":
            options.append(st.floats(0.1, 0.9).map(lambda x: 2 + x))  # a non-integer
        return st.one_of(options)
    if f.kind == "bool":
        return st.one_of(nonfinite, st.integers(0, 1), text)
    if f.kind == "str":
        options = [nonfinite, st.floats(-1e3, 1e3), st.lists(text, min_size=1, max_size=2)]
        if f.choices is not None:
            options.append(text.filter(lambda s: s not in f.choices))
        return st.one_of(options)
    # lists
    options = [st.floats(-1e3, 1e3), text.map(lambda s: s or "x")]
    if f.kind == "floats":
        options.append(nonfinite.map(lambda v: [0.0, v]))
        if key.endswith("_mm"):
            options.append(st.floats(2e6, 1e300).map(lambda v: [0.0, v]))
    elif f.kind == "points":
        options.append(nonfinite.map(lambda v: [[0.0, 1.0], [v, 2.0]]))
        options.append(st.floats(2e6, 1e300).map(lambda v: [[0.0, 1.0], [v, 2.0]]))
    elif f.choices is not None:
        options.append(text.filter(lambda s: s not in f.choices).map(lambda s: [s]))
    if f.default is None:
        options.append(st.just([]))
    return st.one_of(options)


@st.composite
def bad_override(draw):
    path = draw(st.sampled_from(CONFIGS))
    command = draw(st.sampled_from(COMMANDS))
    # the sections that apply to this scene (a process: its base sections)
    sections = sorted(s for s in load_document(path) if s != "process")
    section = draw(st.sampled_from(sections))
    if draw(st.integers(0, 9)) == 0:  # an unknown key
        key = draw(
            st.text(alphabet="abcdefgh_", min_size=1, max_size=8).filter(
                lambda k: k not in SCHEMA[section]
            )
        )
        return path, command, f"{section}.{key}=1", f"{section}.{key}"
    key = draw(st.sampled_from(sorted(SCHEMA[section])))
    value = draw(bad_values(section, key))
    return path, command, f"{section}.{key}={_toml(value)}", f"{section}.{key}"


@settings(
    max_examples=300, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow]
)
@given(case=bad_override())
def test_bad_config_value_is_refused_before_compiling(case, tmp_path_factory):
    path, command, override, key = case
    out = tmp_path_factory.getbasetemp() / "out"
    assert_refused(base_argv(command, path, out) + ["--set", override], key)


@st.composite
def bad_file(draw):
    kind = draw(st.sampled_from(["missing", "folder", "binary", "empty", "broken"]))
    command = draw(st.sampled_from(COMMANDS))
    payload = draw(st.binary(min_size=0, max_size=64))
    return kind, command, payload


@settings(
    max_examples=60,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(case=bad_file())
def test_bad_config_file_is_refused(case, tmp_path):
    kind, command, payload = case
    path = {"missing": tmp_path / "no_such.toml", "folder": tmp_path}.get(kind, tmp_path / "c")
    if kind == "binary":  # never UTF-8: a lone continuation byte first
        path.write_bytes(b"\x80" + payload)
    elif kind == "empty":
        path.write_bytes(b"")
    elif kind == "broken":
        path.write_text("[billet\n")
    argv = [command, str(path)] + (
        ["--out", str(tmp_path / "o")] if command != "taylor-test" else []
    )
    assert_refused(argv, str(path))


@pytest.mark.parametrize("command", COMMANDS)
def test_bom_prefixed_config_is_accepted(command, tmp_path):
    """A UTF-8 byte-order mark before a valid config: accepted (the stub is reached)."""
    bom = tmp_path / "bom.toml"
    bom.write_bytes(b"\xef\xbb\xbf" + (ROOT / "configs/upsetting_seed.toml").read_bytes())
    with pytest.raises(Reached):
        run_cli(base_argv(command, bom, tmp_path / "out"))
