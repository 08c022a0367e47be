"""Writing results: CSV tables (and, for scenes, fields through meshio)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def write_csv(path: Path, columns: dict[str, np.ndarray], fmt: str = "%.10g") -> None:
    """Write equal-length columns with a header line of their names."""
    names = list(columns)
    data = np.column_stack([np.asarray(columns[n], dtype=float) for n in names])
    np.savetxt(path, data, delimiter=",", header=",".join(names), comments="", fmt=fmt)


def read_csv(path: Path) -> dict[str, np.ndarray]:
    data = np.genfromtxt(path, delimiter=",", names=True)
    return {n: np.asarray(data[n]) for n in data.dtype.names}
