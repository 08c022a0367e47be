"""How jaxform's top-level programs are compiled: ``jax.jit`` with per-program options.

jaxform sets no global XLA flag (no ``XLA_FLAGS`` on import).  Its top-level programs
(the load-step chunk, the differentiable trajectory, batched designs, ...) are built with
:func:`jit`, which is ``jax.jit`` plus the compiler options below for the backend the
program runs on, chosen when it is first called.

CPU: YNNPACK fusions off (``xla_cpu_experimental_ynn_fusion_type`` empty).  Recent
XLA:CPU hands small dot products and reductions to YNNPACK; in jaxform's element
routines those are 3x3 tensor products batched over Gauss points and forward-mode
tangents, where a library call per fusion costs more than XLA's own loop (measured: the
documentation's benchmarks page, "Measurements behind the code").

CPU: two HLO passes off (``xla_disable_hlo_passes``), ``while-loop-invariant-code-motion``
and ``simplify-while-loops``.  jaxform's programs are nested while loops (load steps,
Newton iterations, cutbacks, the local Anand solves) over code that already computes its
loop invariants outside the loops; XLA ran these two passes over every loop body at each
round of its simplification pipeline, and they took about half of the compile time of the
load-step chunk (benchmarks page, "Compile time") for no measurable gain at run time.

A jaxlib that does not know an option compiles without the options (checked once per
process).

Other backends: plain ``jax.jit``.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

CPU_OPTIONS = {
    "xla_cpu_experimental_ynn_fusion_type": "",
    "xla_disable_hlo_passes": "while-loop-invariant-code-motion,simplify-while-loops",
}


@functools.cache
def _cpu_options_supported() -> bool:
    try:
        arg = jax.ShapeDtypeStruct((2,), jnp.float32)  # no eager program to make one
        jax.jit(lambda a: a + 1.0, compiler_options=CPU_OPTIONS).lower(arg).compile()
    except Exception:  # an older jaxlib: unknown option
        return False
    return True


def compiler_options(backend: str | None = None) -> dict | None:
    """The options for programs on ``backend`` (default: JAX's default backend)."""
    backend = backend or jax.default_backend()
    if backend == "cpu" and _cpu_options_supported():
        return dict(CPU_OPTIONS)
    return None


def jit(fun=None, **jit_kwargs):
    """``jax.jit(fun, **jit_kwargs)`` compiled with :func:`compiler_options`.

    Usable as ``jit(f, static_argnums=...)`` or as a decorator
    ``@partial(jit, static_argnums=...)``.  The jitted function is built on the first
    call (per default backend) and reused; ``.lower(...)`` lowers it as ``jax.jit``'s
    does.  Called while tracing (inside another jit, grad or vmap, where XLA accepts
    compiler options only on the outermost program) it is the plain ``jax.jit``: the
    outer program's options apply."""
    if fun is None:
        return functools.partial(jit, **jit_kwargs)
    return _Jitted(fun, jit_kwargs)


class _Jitted:
    def __init__(self, fun, jit_kwargs):
        functools.update_wrapper(self, fun)
        self._fun, self._kwargs, self._built = fun, jit_kwargs, {}

    def _for(self, args, kwargs):
        traced = any(
            isinstance(a, jax.core.Tracer) for a in jax.tree_util.tree_leaves((args, kwargs))
        )
        key = "traced" if traced else jax.default_backend()
        f = self._built.get(key)
        if f is None:
            opts = None if traced else compiler_options(key)
            f = self._built[key] = jax.jit(self._fun, compiler_options=opts, **self._kwargs)
        return f

    def __call__(self, *args, **kwargs):
        return self._for(args, kwargs)(*args, **kwargs)

    def lower(self, *args, **kwargs):
        return self._for(args, kwargs).lower(*args, **kwargs)
