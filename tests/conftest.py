"""Test-wide set-up: float64, the one documented switch (jaxform.precision), and a
persistent compilation cache shared by the test files and the xdist workers of a run.

The cache lives under the repository's ``.pytest_cache`` (one sub-directory per
jax/jaxlib/klujax versions, :func:`jaxform.cache.version_tag`), so a program compiled by
one test file, or by the previous run, is loaded by the next; ``JAXFORM_CACHE_DIR`` is
set to it for the jaxform processes the tests start.  A cache directory given
through ``JAX_COMPILATION_CACHE_DIR`` or ``JAXFORM_CACHE_DIR`` is used instead;
``JAXFORM_CACHE_DIR=off`` disables it (to time cold compiles).

Scheduling (``--dist loadgroup``, pyproject.toml): each test file is one xdist group (its
tests share compiled programs through module-level caches), except the tests named in
:data:`OWN_GROUP`, which compile programs no other test in their file uses and go to
whichever worker is free.  The groups are handed out longest first (:data:`GROUP_SECONDS`,
then by number of tests), so a long file never starts last while the other worker idles.

Memory maps: a worker keeps every program it compiled (JAX's caches, module-level
programs of the test files, :mod:`jaxform.program_store`), each holding memory maps of the
process, and XLA aborts the worker once Linux's ``vm.max_map_count`` is reached (the
default suite crossed it after about 20 minutes).  After each test the worker lets its
programs go once it holds half the limit (:func:`jaxform.program_store.release_if_crowded`).
"""

import os
from pathlib import Path

import jax
import pytest

import jaxform
from jaxform import program_store
from jaxform.cache import ENV_VAR, MIN_COMPILE_TIME_S, OFF, version_tag

jaxform.enable_x64()


def pytest_configure(config):
    if os.environ.get("JAX_COMPILATION_CACHE_DIR"):
        return  # JAX reads it itself
    if os.environ.get(ENV_VAR, "auto").strip().lower() in OFF:
        return
    root = (
        Path(os.environ[ENV_VAR]).expanduser()
        if os.environ.get(ENV_VAR)
        else config.rootpath / ".pytest_cache" / "jax-compilation-cache"
    )
    path = root / version_tag()
    path.mkdir(parents=True, exist_ok=True)
    os.environ[ENV_VAR] = str(root)  # jaxform processes the tests start use it too
    jax.config.update("jax_compilation_cache_dir", str(path))
    if "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS" not in os.environ:
        jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_TIME_S)


# Seconds of one worker's time per group on a cold cache (a file, or a test of
# OWN_GROUP): the default suite's run of 2026-11-27 with --durations=0 (2 workers on a
# 2-core CPU at a load of ~8, so about 3x a quiet machine's; docs/benchmarks.md).  Only
# the order depends on them: a group missing here counts as short.  Refresh them from
# such a run when the files grow.
GROUP_SECONDS = {
    "test_upsetting": 927.0,
    "test_remesh_gradients": 631.0,
    "test_friction": 554.0,
    "test_verification": 519.0,
    "test_remesh": 433.0,
    "test_friction_per_die": 398.0,
    "test_materials": 384.0,
    "test_thermal": 349.0,
    "test_upsetting::test_compact_point_tangent_equals_the_plain_derivatives": 344.0,
    "test_gradients": 298.0,
    "test_modified_newton": 291.0,
    "test_batch": 275.0,
    "test_forming_outputs": 274.0,
    "test_layout": 186.0,
    "test_studies": 177.0,
    "test_cli": 162.0,
    "test_cache": 156.0,
    "test_api": 139.0,
    "test_process": 122.0,
    "test_several_dies": 64.0,
    "test_presses": 58.0,
    "test_die_geometry": 56.0,
    "test_program_store": 55.0,
    "test_container": 49.0,
}

# Tests that compile programs no other test of their file uses: a group each (named
# file::test), so the two workers can split a long file.
OWN_GROUP = ("test_upsetting::test_compact_point_tangent_equals_the_plain_derivatives",)


def _group(item) -> str:
    """The file's stem, or file::test for a test of OWN_GROUP (parameters dropped)."""
    path, _, rest = item.nodeid.split("@", 1)[0].partition("::")
    stem = path.rsplit("/", 1)[-1].removesuffix(".py")
    name = f"{stem}::{rest.split('[', 1)[0]}"
    return name if name in OWN_GROUP else stem


@pytest.hookimpl(tryfirst=True)  # the order only; the groups are marked at collection
def pytest_collection_modifyitems(config, items):
    groups = [_group(item) for item in items]
    count, first = {}, {}
    for i, g in enumerate(groups):
        count[g] = count.get(g, 0) + 1
        first.setdefault(g, i)

    def key(i):
        g = groups[i]
        return (-GROUP_SECONDS.get(g, 0.0), -count[g], first[g], i)

    items[:] = [items[i] for i in sorted(range(len(items)), key=key)]


def pytest_itemcollected(item):
    """Each test's xdist group, marked as it is collected, so that xdist's worker finds
    the marks in its ``pytest_collection_modifyitems`` whatever the order of the hooks.
    (It names the group in the test's node id, which works with pytest < 9.2 only:
    pyproject.toml.)"""
    item.add_marker(pytest.mark.xdist_group(_group(item)))


def pytest_runtest_teardown(item, nextitem):
    program_store.release_if_crowded()


# What a worker ran, in order: a failure that a fresh process does not repeat (a flake of
# the process's state) is reproduced by running these before it.
_ran: list[str] = []
_reran: list[str] = []  # the failures rerun in a fresh process (the first only)
RERUN_TIMEOUT_S = 900


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    """On a worker's first failing test: rerun it alone in a fresh process and add to the
    report whether it passes there, with the tests this worker ran before it and its
    share of the memory-map limit.  The outcome stays a failure; this only says whether
    the failure belongs to the test or to the state the process was in."""
    outcome = yield
    report = outcome.get_result()
    if call.when != "call":
        return
    _ran.append(item.nodeid)
    if not report.failed or _reran or os.environ.get("JAXFORM_TEST_RERUN") == "off":
        return
    _reran.append(item.nodeid)
    import subprocess
    import sys

    cmd = [sys.executable, "-m", "pytest", item.nodeid.split("@")[0], "-n", "0", "-q",
           "-p", "no:cacheprovider", "-m", ""]  # fmt: skip
    env = dict(os.environ, JAXFORM_TEST_RERUN="off")
    try:
        done = subprocess.run(cmd, cwd=str(item.config.rootpath), env=env, timeout=RERUN_TIMEOUT_S,
                              capture_output=True, text=True)  # fmt: skip
        verdict = "passed" if done.returncode == 0 else f"failed (exit {done.returncode})"
        tail = done.stdout.strip().splitlines()[-1:] if done.stdout else []
    except subprocess.TimeoutExpired:
        verdict, tail = f"did not end within {RERUN_TIMEOUT_S} s", []
    report.sections.append((
        "the same test in a fresh process",
        f"{verdict} {' '.join(tail)}\nmap share of this worker: "
        f"{program_store.map_share():.3f}\nthis worker ran before it ({len(_ran) - 1} tests):\n"
        + "\n".join(_ran[:-1]),
    ))  # fmt: skip
