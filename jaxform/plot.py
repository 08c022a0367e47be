"""PNG figures (matplotlib, Agg backend: no display needed)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def stress_strain(curves: dict[str, tuple[np.ndarray, np.ndarray]], path: Path, title: str):
    """curves: label -> (true strain, stress in MPa)."""
    fig, ax = plt.subplots(figsize=(6, 4.2))
    for label, (eps, sig) in curves.items():
        ax.plot(eps, sig, label=label)
    ax.set_xlabel("true strain [-]")
    ax.set_ylabel("true stress [MPa] (compression positive)")
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
