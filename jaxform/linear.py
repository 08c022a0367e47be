"""Linear solve backends behind one interface, both usable inside jit.

A matrix is given as values ``vals`` on a fixed sparsity pattern (unique rows/cols
computed once at set-up, passed in as *arguments* so that no large constant is baked
into the compiled program).  ``solve(rows, cols, vals, b, n)``:

* ``dense``  scatters into an n x n array and calls LU (jnp.linalg.solve);
* ``sparse`` calls klujax (SuiteSparse KLU as an XLA primitive).  klujax is imported
  lazily, only when this backend is used, because importing it switches JAX to CPU
  and float64 process-wide.

``auto`` picks by size.  Measured on the seed scene (2 cores, experiments/bench_seed.py,
run time of the whole scene): 55 unknowns dense 0.11 s / sparse 0.12 s, 119 unknowns
0.24 / 0.22 s, 384 unknowns 1.29 / 0.84 s; one solve at 384 unknowns 3.4 ms dense vs
0.8 ms sparse.  So dense only below 100 unknowns.

``solve_transpose`` solves A^T y = b with the same pattern (for adjoints).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp

DENSE_LIMIT = 100  # unknowns; 'auto' picks dense below this
BACKENDS = ("auto", "dense", "sparse")


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
    if name not in BACKENDS:
        raise ValueError(f"solver.linear = {name!r}: must be one of {', '.join(BACKENDS)}")
    if name == "auto":
        name = "dense" if n_unknowns < DENSE_LIMIT else "sparse"
    return LinearSolver(name)
