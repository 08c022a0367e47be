"""Host-side damage and die-wear results of a run (NumPy): what a forging engineer judges.

* :func:`damage_columns`: per history row and damage criterion
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


def damage_columns(scene, x, damage) -> dict[str, float]:
    """The history columns of one row on ``scene``'s mesh: ``x`` its unknowns (displacement
    from ``scene.inputs.coords``), ``damage`` its Gauss-point damage (ne, 4, 3); the
    critical value and criterion of the flag count from ``scene.settings.output``."""
    out = scene.settings.output
    gp = gauss_points(positions(scene, x), np.asarray(scene.mesh.elements)).reshape(-1, 2)
    flat = np.asarray(damage).reshape(-1, len(CRITERIA))
    cols = {}
    for i, name in enumerate(CRITERIA):
        j = int(np.argmax(flat[:, i]))
        cols[f"damage_{name}_max"] = float(flat[j, i])
        cols[f"damage_{name}_r_mm"] = float(gp[j, 0])
        cols[f"damage_{name}_z_mm"] = float(gp[j, 1])
    if out.damage_critical > 0.0:
        flags = damage_flags(damage, out.damage_critical, out.damage_criterion)
        cols["damage_flagged"] = float(flags.sum())
    return cols


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
