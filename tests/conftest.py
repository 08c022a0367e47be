"""Test-wide set-up: float64, the one documented switch (jaxform.precision), and a
persistent compilation cache shared by the test files and the xdist workers of a run.

The cache lives under the repository's ``.pytest_cache`` (one sub-directory per
jax/jaxlib/klujax versions, :func:`jaxform.cache.version_tag`), so a program compiled by
one test file, or by the previous run, is loaded by the next; ``JAXFORM_CACHE_DIR`` is
set to it for the jaxform processes the tests start.  A cache directory given
through ``JAX_COMPILATION_CACHE_DIR`` or ``JAXFORM_CACHE_DIR`` is used instead;
``JAXFORM_CACHE_DIR=off`` disables it (to time cold compiles)."""

import os
from pathlib import Path

import jax

import jaxform
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
