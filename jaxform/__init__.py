"""jaxform: differentiable finite-element simulation of metal forming in JAX.

Importing jaxform changes no global JAX setting; call :func:`enable_x64` first
(see :mod:`jaxform.precision`), and :func:`enable_compilation_cache` for a warm start
(see :mod:`jaxform.cache`; the command line and :func:`jaxform.driver.run` call it).
"""

from jaxform.cache import enable_compilation_cache
from jaxform.precision import enable_x64, require_x64

__all__ = ["enable_compilation_cache", "enable_x64", "require_x64"]
__version__ = "0.1.0"
