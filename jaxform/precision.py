"""The one place where jaxform asks JAX for float64.

jaxform computes in float64 throughout: the Newton solver converges to a relative
residual of 1e-10 and the tests compare against finite differences at 1e-6, neither of
which float32 can hold.  Importing jaxform changes no global JAX setting.  Instead:

* the command line (`jaxform ...`) calls :func:`enable_x64` before it builds anything;
* library users call ``jaxform.enable_x64()`` once, at the top of their script;
* the public entry points (`jaxform.run`, the material-point driver, ...) call
  :func:`require_x64`, which raises a clear error if float64 is off, rather than
  silently computing in float32.
"""

from __future__ import annotations

import jax


def enable_x64() -> None:
    """Switch JAX to float64 for this process (idempotent); call it before building a
    scene.

    Arguments:
        none.

    Returns:
        None.
    """
    jax.config.update("jax_enable_x64", True)


def x64_enabled() -> bool:
    return bool(jax.config.jax_enable_x64)


def require_x64() -> None:
    """Raise if float64 is off: jaxform's tolerances are float64 tolerances.

    Arguments:
        none.

    Returns:
        None; raises RuntimeError (saying to call :func:`enable_x64`) when float64 is off.
    """
    if not x64_enabled():
        raise RuntimeError(
            "jaxform needs float64: call jaxform.enable_x64() before building a scene "
            "(or set the environment variable JAX_ENABLE_X64=1)."
        )
