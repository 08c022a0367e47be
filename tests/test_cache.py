"""Warm start (jaxform.cache): where the compilation cache goes, that a second process
loads the programs the first wrote, and that importing jaxform changes no JAX setting.

Processes are started with a clean environment for the cache variables (no
``JAX_COMPILATION_CACHE_DIR``), so the test suite's own cache (tests/conftest.py) is not
involved; JAX's own events (``/jax/compilation_cache/...``: compile requests, hits, and
"misses", counted when an entry is written) are counted."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from jaxform import program_store
from jaxform.cache import ENV_VAR, default_cache_root, resolve_cache_dir, version_tag

ROOT = Path(__file__).resolve().parents[1]
# klujax with modified Newton: custom calls, and factorizations freed inside the program
TINY = [
    "--set",
    "mesh.nr=3",
    "--set",
    "mesh.nz=3",
    "--set",
    "time.dt_s=20.0",
    "--set",
    "die.reduction=0.3",
    "--set",
    "output.fields=false",
    "--set",
    "output.plots=false",
    "--set",
    "solver.linear=sparse",
    "--set",
    "solver.newton=modified",
]

# runs `jaxform.cli.main(argv)` and prints the cache events of the process as JSON
PROBE = """
import json, sys
import jax
counts = {"requests": 0, "hits": 0, "written": 0}
names = {"requests": "compile_requests_use_cache", "hits": "cache_hits",
         "written": "cache_misses"}  # JAX counts a miss when it writes the entry
def on_event(event, **kw):
    for key, name in names.items():
        if event == "/jax/compilation_cache/" + name:
            counts[key] += 1
jax.monitoring.register_event_listener(on_event)
from jaxform.cli import main
code = main(sys.argv[1:])
print("PROBE " + json.dumps(dict(counts, code=code,
                                 cache_dir=jax.config.jax_compilation_cache_dir)))
"""


def _env(**set_vars):
    env = {
        k: v
        for k, v in os.environ.items()
        if k
        not in (
            ENV_VAR,
            "JAX_COMPILATION_CACHE_DIR",
            "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS",
            "XDG_CACHE_HOME",
        )
    }
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    env.update(set_vars)
    return env


def _probe(argv, env):
    proc = subprocess.run(
        [sys.executable, "-c", PROBE, *argv],
        env=env,
        cwd=ROOT,
        check=False,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    line = [s for s in proc.stdout.splitlines() if s.startswith("PROBE ")][-1]
    return json.loads(line[len("PROBE ") :])


def _files(path: Path, stored: bool = False) -> set:
    """The compilation cache's files under ``path`` (``stored``: the stored programs',
    jaxform.program_store, in its ``exported`` folders, instead)."""
    if not path.exists():
        return set()
    return {p.name for p in path.rglob("*")
            if p.is_file() and (p.parent.name == program_store.SUBDIR) == stored}  # fmt: skip


def test_second_process_loads_every_program_from_the_cache(tmp_path):
    """Reference: a run of the 3 x 3 seed scene (klujax, modified Newton: its chunk frees
    the factorizations it replaces from inside the program, through an FFI call since a
    host callback kept the program out of the cache) writes each of its programs (minimum
    compile time 0 s here), one file per cache miss, and a second
    identical process compiles none: every compile request a hit, no new file (the chunk's
    compiled program read from the store's own file, not requested).  The config key
    then moves the cache: with JAXFORM_CACHE_DIR=off and [solver] compilation_cache_dir
    pointing at the same directory, the run loads every program from there."""
    cache = tmp_path / "cache"
    argv = ["run", "configs/upsetting_seed.toml", *TINY, "--out", str(tmp_path / "out")]
    env = _env(**{ENV_VAR: str(cache), "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0"})
    cold = _probe(argv, env)
    written = _files(cache)
    assert cold["code"] == 0 and cold["cache_dir"] == str(cache / version_tag())
    # every program compiled is written (none refused, e.g. for a host callback); one
    # compiled again in the same process is a hit
    assert cold["written"] > 0 and cold["requests"] == cold["hits"] + cold["written"]
    assert len(written) == cold["written"] and all(f.endswith("-cache") for f in written)
    # the chunk's traced program (.bin), output tree and compiled program (.xla)
    stored = _files(cache, stored=True)
    assert sorted(f.rsplit(".", 1)[1] for f in stored) == ["bin", "tree", "xla"]

    warm = _probe(argv, env)
    assert warm["code"] == 0
    # the chunk's compiled program comes from its own file, not through JAX's cache
    loaded = cold["requests"] - 1
    assert (warm["requests"], warm["hits"], warm["written"]) == (loaded, loaded, 0)
    assert _files(cache) == written and _files(cache, stored=True) == stored

    env_off = dict(env, **{ENV_VAR: "off"})
    moved = _probe(argv + ["--set", f"solver.compilation_cache_dir={cache}"], env_off)
    assert moved["cache_dir"] == str(cache / version_tag())
    assert (moved["requests"], moved["hits"]) == (loaded, loaded)


ENABLE = """
import json, sys
import jax
from jaxform.cache import enable_compilation_cache
out = {"initial": jax.config.jax_compilation_cache_dir}
out["auto"] = str(enable_compilation_cache())
out["auto_jax"] = jax.config.jax_compilation_cache_dir
out["moved"] = str(enable_compilation_cache(sys.argv[1]))
out["moved_jax"] = jax.config.jax_compilation_cache_dir
out["auto_again"] = str(enable_compilation_cache("auto"))
out["off"] = str(enable_compilation_cache("off"))
out["off_jax"] = jax.config.jax_compilation_cache_dir
out["min_time"] = jax.config.jax_persistent_cache_min_compile_time_secs
print("ENABLE " + json.dumps(out))
"""


def _enable(tmp_path, **set_vars):
    proc = subprocess.run(
        [sys.executable, "-c", ENABLE, str(tmp_path / "moved")],
        check=False,
        env=_env(**set_vars),
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    line = [s for s in proc.stdout.splitlines() if s.startswith("ENABLE ")][-1]
    return json.loads(line[len("ENABLE ") :])


def test_environment_variable_and_argument_move_and_disable_the_cache(tmp_path):
    """Reference: the rules of jaxform.cache, read off JAX's own setting
    (jax_compilation_cache_dir) after each call, exact strings."""
    tag = version_tag()
    out = _enable(tmp_path, **{ENV_VAR: str(tmp_path / "env"), "XDG_CACHE_HOME": str(tmp_path)})
    assert out["initial"] is None
    assert out["auto"] == out["auto_jax"] == str(tmp_path / "env" / tag)
    assert out["moved"] == out["moved_jax"] == str(tmp_path / "moved" / tag)
    assert out["auto_again"] == str(tmp_path / "moved" / tag)  # auto keeps what is set
    assert out["off"] == "None" and out["off_jax"] is None
    assert out["min_time"] == 0.0  # JAX's 1 s default replaced
    assert (tmp_path / "env" / tag).is_dir() and (tmp_path / "moved" / tag).is_dir()

    out = _enable(tmp_path, XDG_CACHE_HOME=str(tmp_path / "xdg"))  # no JAXFORM_CACHE_DIR
    assert out["auto"] == str(tmp_path / "xdg" / "jaxform" / tag)

    out = _enable(tmp_path, **{ENV_VAR: "off", "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "2"})
    assert out["auto"] == "None" and out["auto_jax"] is None  # disabled by the variable
    assert out["moved"] == str(tmp_path / "moved" / tag)  # an explicit path still counts
    assert out["min_time"] == 2.0  # the user's setting kept

    out = _enable(tmp_path, JAX_COMPILATION_CACHE_DIR=str(tmp_path / "jax"))
    assert out["initial"] == out["auto"] == out["auto_jax"] == str(tmp_path / "jax")


@pytest.mark.parametrize(
    "env_value, argument, expected",
    [
        (None, None, "xdg"),
        (None, "auto", "xdg"),
        ("", None, None),
        ("off", None, None),
        ("OFF", "auto", None),
        ("/some/where", None, "/some/where"),
        ("/some/where", "/else", "/else"),
        ("/some/where", "off", None),
        (None, "none", None),
    ],
)
def test_resolve_cache_dir(monkeypatch, tmp_path, env_value, argument, expected):
    """Reference: the precedence list of jaxform.cache (argument, then JAXFORM_CACHE_DIR,
    then $XDG_CACHE_HOME/jaxform), each directory with the version sub-directory."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    if env_value is None:
        monkeypatch.delenv(ENV_VAR, raising=False)
    else:
        monkeypatch.setenv(ENV_VAR, env_value)
    got = resolve_cache_dir(argument)
    if expected is None:
        assert got is None
    elif expected == "xdg":
        assert got == tmp_path / "jaxform" / version_tag() == default_cache_root() / version_tag()
    else:
        assert got == Path(expected) / version_tag()


def test_config_key_has_a_default_that_defers_to_the_environment():
    """Reference: the schema ([solver] compilation_cache_dir = 'auto'), and a dumped
    config keeps a value given."""
    from jaxform.config import load_config

    cfg = load_config(ROOT / "configs/upsetting_seed.toml")
    assert cfg["solver"]["compilation_cache_dir"] == "auto"
    cfg = load_config(ROOT / "configs/upsetting_seed.toml", ["solver.compilation_cache_dir=/tmp/x"])
    assert cfg["solver"]["compilation_cache_dir"] == "/tmp/x"


def test_importing_jaxform_changes_no_jax_setting():
    """Reference: every entry of jax.config.values before and after importing jaxform
    and its entry-point modules (exact equality), in a fresh process."""
    code = """
import jax
before = dict(jax.config.values)
import jaxform, jaxform.cache, jaxform.cli, jaxform.driver
after = dict(jax.config.values)
changed = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))
print("CHANGED", changed, len(before))
"""
    proc = subprocess.run(
        [sys.executable, "-c", code],
        env=_env(),
        cwd=ROOT,
        check=False,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    line = [s for s in proc.stdout.splitlines() if s.startswith("CHANGED")][-1]
    assert line.startswith("CHANGED [] ") and int(line.split()[-1]) > 50


def test_free_in_program_frees_exactly_the_valid_factorizations(monkeypatch):
    """Reference: the handles the compiled program returns.  LinearSolver.release (the
    FFI call of jaxform.klu_free, in place of a host callback) closes, through
    klujax_cpp.KLUNumeric, each valid handle once and no invalid one, also batched
    (handles (2, 1), flags (2,)); its result is an int32 zero of the flags' shape."""
    import jax
    import jax.numpy as jnp
    import klujax_cpp
    import numpy as np

    from jaxform.klu import symbolic as klu_symbolic
    from jaxform.linear import KLU, Factorization

    closed = []
    real = klujax_cpp.KLUNumeric

    class Recording:
        def __init__(self, handles):
            self.inner = real(handles)
            self.handles = list(handles)

        def close(self):
            closed.extend(self.handles)
            self.inner.close()

    monkeypatch.setattr(klujax_cpp, "KLUNumeric", Recording)
    rows = jnp.array([0, 1, 2, 0], jnp.int32)
    cols = jnp.array([0, 1, 2, 2], jnp.int32)
    lin = KLU()
    sym = klu_symbolic(rows, cols, 3)

    @jax.jit
    def two_factorizations(vals, flags):
        empty = lin.empty_factorization(3, vals.dtype)
        a = lin.refactor(rows, cols, vals, 3, sym, empty)
        b = lin.refactor(rows, cols, 2.0 * vals, 3, sym, empty)
        both = jax.tree_util.tree_map(lambda u, v: jnp.stack([u, v]), a, b)
        token = lin.release(Factorization(lu=both.lu, piv=both.piv, valid=flags, count=both.count))
        return both.lu, token

    lu, token = two_factorizations(jnp.array([2.0, 3.0, 4.0, 1.0]), jnp.array([True, False]))
    lu = np.asarray(lu)
    assert token.dtype == jnp.int32 and token.shape == (2,) and not np.asarray(token).any()
    assert closed == [int(lu[0, 0])]
    lin.release_now(Factorization(lu=lu[1], piv=None, valid=np.asarray(True), count=None))
    assert closed == [int(lu[0, 0]), int(lu[1, 0])]


def test_a_worker_runs_its_files_tests_as_one_group(request):
    """Under the suite's ``--dist loadgroup`` (pyproject.toml) a test's node id carries its
    xdist group, the file's stem (tests/conftest.py): the mark that sends a file's tests to
    one worker, which shares their compiled programs.  With pytest 9.2 and pytest-xdist 3.8
    the suffix was lost and every file's tests were split across the workers."""
    if not os.environ.get("PYTEST_XDIST_WORKER") or not request.config.getvalue("loadgroup"):
        pytest.skip("a run without --dist loadgroup has no groups")
    assert request.node.nodeid.endswith("@test_cache"), request.node.nodeid
