"""jaxform: differentiable finite-element simulation of metal forming in JAX.

Importing jaxform changes no global JAX setting; call :func:`enable_x64` first
(see :mod:`jaxform.precision`).
"""

from jaxform.precision import enable_x64, require_x64

__all__ = ["enable_x64", "require_x64"]
__version__ = "0.1.0"
