"""Linear solve backends behind one interface, both usable inside jit.

A matrix is given as values ``vals`` on a fixed sparsity pattern (unique rows/cols
computed once at set-up, passed in as *arguments* so that no large constant is baked
into the compiled program).  ``solve(rows, cols, vals, b, n)``:

* ``dense``  scatters into an n x n array and calls LU (jnp.linalg.solve): best for
  small systems (a few thousand unknowns);
* ``sparse`` calls klujax (SuiteSparse KLU as an XLA primitive).  klujax is imported
  lazily, only when this backend is chosen, because importing it switches JAX to CPU
  and float64 process-wide.

``solve_transpose`` solves A^T y = b with the same pattern (for adjoints).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp

DENSE_LIMIT = 3000  # unknowns; 'auto' picks dense below this


@dataclass(frozen=True)
class LinearSolver:
    backend: str = "dense"  # 'dense' | 'sparse'

    def solve(self, rows, cols, vals, b, n: int):
        if self.backend == "dense":
            a = jnp.zeros((n, n), dtype=vals.dtype).at[rows, cols].set(vals)
            return jnp.linalg.solve(a, b)
        import klujax  # lazy: see module docstring

        return klujax.solve(rows.astype(jnp.int32), cols.astype(jnp.int32), vals, b)

    def solve_transpose(self, rows, cols, vals, b, n: int):
        return self.solve(cols, rows, vals, b, n)


def choose_backend(name: str, n_unknowns: int) -> LinearSolver:
    if name == "auto":
        name = "dense" if n_unknowns < DENSE_LIMIT else "sparse"
    if name == "sparse":
        try:
            import klujax  # noqa: F401
        except ImportError as exc:  # pragma: no cover - depends on the install
            raise RuntimeError(
                "solver.linear = 'sparse' needs klujax: pip install -e '.[sparse]' "
                "(or set solver.linear = 'dense')"
            ) from exc
    if name not in ("dense", "sparse"):
        raise ValueError(f"solver.linear = {name!r}: must be one of auto, dense, sparse")
    return LinearSolver(name)
