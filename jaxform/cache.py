"""Warm start: JAX's persistent compilation cache, on by default at jaxform's entry points.

A second run of the same scene loads its compiled programs from disk instead of
compiling them again.  Importing jaxform changes nothing; :func:`enable_compilation_cache`
is called by the command line and :func:`jaxform.driver.run` (library users who build
scenes themselves call it once, like :func:`jaxform.enable_x64`).

Where (first that applies):

1. a ``path`` argument (the config key ``[solver] compilation_cache_dir``): a directory,
   or ``"off"`` to disable; ``"auto"`` (the key's default) goes on down this list;
2. a cache directory JAX was already given (``JAX_COMPILATION_CACHE_DIR``,
   ``jax.config``, a test harness): left as it is;
3. the environment variable ``JAXFORM_CACHE_DIR``: a directory, or ``off`` / ``0`` /
   ``none`` / empty to disable;
4. the per-user cache directory: ``$XDG_CACHE_HOME/jaxform``, default ``~/.cache/jaxform``.

The programs go to a sub-directory named after the jax, jaxlib and klujax versions
(``jax-0.10.2_jaxlib-0.10.2_klujax-0.5.2``): JAX's own key covers the program (its HLO,
hence jaxform's code), the compiler options and the jax/jaxlib versions, but not the
code behind a custom call (klujax), which a new klujax may change under the same name.
Every program is written, however quick its compile (:data:`MIN_COMPILE_TIME_S`; JAX's
default, 1 s, would leave out the many small programs of a run, which add up), unless the
process set ``jax_persistent_cache_min_compile_time_secs`` itself.  A directory that
cannot be created gives a :class:`CompilationCacheWarning` and a run without the cache.

JAX refuses to write a program with a host callback (``io_callback``, ``jax.debug.print``):
such a program compiles on every run.  jaxform's own programs have none (the klujax
factorizations freed inside a program go through an FFI call, :mod:`jaxform.klu_free`).

The cache is trusted code: whoever can write to the directory can make jaxform run
arbitrary code, so it lives in the user's own cache directory.
"""

from __future__ import annotations

import os
import warnings
from importlib import metadata
from pathlib import Path

ENV_VAR = "JAXFORM_CACHE_DIR"
OFF = ("", "off", "0", "none", "false", "no")
MIN_COMPILE_TIME_S = 0.0
_JAX_DEFAULT_MIN_COMPILE_TIME_S = 1.0


class CompilationCacheWarning(UserWarning):
    """The compilation cache directory could not be used; the run goes on without it."""


def default_cache_root() -> Path:
    """``$XDG_CACHE_HOME/jaxform``, or ``~/.cache/jaxform``."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "jaxform"


def version_tag() -> str:
    """The sub-directory name: the versions of the packages that make the programs."""
    parts = []
    for pkg in ("jax", "jaxlib", "klujax"):
        try:
            parts.append(f"{pkg}-{metadata.version(pkg)}")
        except metadata.PackageNotFoundError:
            parts.append(f"{pkg}-none")
    return "_".join(parts)


def resolve_cache_dir(path: str | os.PathLike | None = None) -> Path | None:
    """The directory :func:`enable_compilation_cache` would use for ``path`` (None: off),
    ignoring a directory JAX was already given."""
    setting = "auto" if path is None else str(path)
    if setting.strip().lower() == "auto":
        if ENV_VAR in os.environ:
            setting = os.environ[ENV_VAR]
            if setting.strip().lower() in OFF:
                return None
        else:
            return default_cache_root() / version_tag()
    elif setting.strip().lower() in OFF:
        return None
    return Path(setting).expanduser() / version_tag()


def enable_compilation_cache(path: str | os.PathLike | None = None) -> Path | None:
    """Point JAX's persistent compilation cache at jaxform's cache directory (see the
    module docstring for which).  Idempotent; call it before the first program.

    Arguments:
        path: None or ``"auto"`` (the default choice), ``"off"``, or a directory (the
            version sub-directory is added).

    Returns:
        The directory in use, or None when the cache is off."""
    import jax
    from jax.experimental.compilation_cache import compilation_cache as cc

    current = jax.config.jax_compilation_cache_dir
    explicit = path is not None and str(path).strip().lower() != "auto"
    if current and not explicit:
        return Path(current)  # the process (or its user) chose a cache already
    target = resolve_cache_dir(path)
    if target is None:
        if current:
            jax.config.update("jax_compilation_cache_dir", None)
            cc.reset_cache()
        return None
    if current != str(target):
        try:
            target.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            warnings.warn(
                f"compilation cache directory {target}: {err}; running without "
                f"the cache (set {ENV_VAR}=off to silence)",
                CompilationCacheWarning,
                stacklevel=2,
            )
            return None
        jax.config.update("jax_compilation_cache_dir", str(target))
        if current:
            cc.reset_cache()  # JAX opens its cache once per process: reopen here
    if (
        jax.config.jax_persistent_cache_min_compile_time_secs == _JAX_DEFAULT_MIN_COMPILE_TIME_S
        and "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS" not in os.environ
    ):
        jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_TIME_S)
    return target
