"""Host-side damage and die-wear results of a run (NumPy): what a forging engineer judges.

* :func:`damage_history`: per history row and damage criterion
  (:data:`jaxform.damage.CRITERIA`), the largest Gauss-point value and where it is
  (``damage_<name>_max``, ``damage_<name>_r_mm``, ``damage_<name>_z_mm``), and with a
  critical value the number of elements that reach it (``damage_flagged``);
* :func:`damage_flags`: per element, whether any of its Gauss points reached the critical
  value of the chosen criterion (the crack-risk map);
* :func:`wear_profiles`: the wear depth at each die's stations at the end of the run,
  with the stations' positions on the die at t = 0 and their arc length.
"""

from __future__ import annotations

import numpy as np

from jaxform.damage import CRITERIA
from jaxform.postprocess import positions
from jaxform.transfer import gauss_points


def damage_flags(damage: np.ndarray, critical: float, criterion: str) -> np.ndarray:
    """(n_elements,) 1.0 where an element's Gauss point reached ``critical`` of
    ``criterion`` (0 everywhere when ``critical`` is 0: no flag asked for)."""
    d = np.asarray(damage)[..., CRITERIA.index(criterion)]
    if not critical > 0.0:
        return np.zeros(len(d))
    return (d.max(axis=1) >= critical).astype(float)


def damage_history(scene, xs, damages, critical: float = 0.0, criterion: str = "cl") -> dict:
    """History columns of one mesh's rows: ``xs`` their unknowns (displacement from
    ``scene.inputs.coords``), ``damages`` their Gauss-point damage (rows, ne, 4, 3)."""
    elements = np.asarray(scene.mesh.elements)
    out: dict[str, list] = {}
    for x, dmg in zip(xs, damages):
        gp = gauss_points(positions(scene, x), elements).reshape(-1, 2)
        flat = np.asarray(dmg).reshape(-1, len(CRITERIA))
        for i, name in enumerate(CRITERIA):
            j = int(np.argmax(flat[:, i]))
            out.setdefault(f"damage_{name}_max", []).append(flat[j, i])
            out.setdefault(f"damage_{name}_r_mm", []).append(gp[j, 0])
            out.setdefault(f"damage_{name}_z_mm", []).append(gp[j, 1])
        if critical > 0.0:
            flagged = damage_flags(dmg, critical, criterion).sum()
            out.setdefault("damage_flagged", []).append(flagged)
    return {k: np.asarray(v, dtype=float) for k, v in out.items()}


def wear_profiles(scene, wear_mm) -> dict[str, dict[str, np.ndarray]]:
    """Per die name: its stations' position at t = 0 (``r_mm``, ``z_mm``), arc length from
    the first station (``s_mm``) and wear depth (``wear_mm``, mm) from ``wear_mm``
    (n_dies, n_stations), the state's.  Empty without wear stations."""
    law = scene.inputs.wear
    if law is None or scene.inputs.die is None:
        return {}
    out = {}
    for i, name in enumerate(scene.inputs.die.names):
        pts = np.asarray(law.stations[i])
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
        out[name] = dict(r_mm=pts[:, 0], z_mm=pts[:, 1], s_mm=s, wear_mm=np.asarray(wear_mm)[i])
    return out
