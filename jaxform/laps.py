"""Laps and pockets: the two ways the free surface of a forging closes on air.

* A **wedge** (a lap, a defect): at a free vertex off the die whose two edges are free,
  the surface turns back on itself; its air-side angle is 180 deg on a straight side,
  270 at a square corner of the section, 0 when the surface has folded flat onto itself
  (material lying on material).  Its **depth** is how far the fold's two faces reach from
  its root: each flank runs from the root along the free surface until it reaches a die,
  leaves the free surface, or has turned away from the wedge by more than FLANK_TURN_DEG
  in all (the mouth); the depth is the shorter flank's length along the surface.
* A **pocket** (underfill along the die): a run of free vertices off the die between two
  vertices that touch a die (gap <= TOUCH_GAP_MM), the material closing on the die from
  both sides with air between them.  Its **gap** is the run's largest gap to the die, its
  **length** the surface's length from one touching vertex to the other, its angle
  atan(gap / half the length) (0 when it closes).

A free surface that meets the die at a contact front, as a side rolling onto the die or
material filling a die corner, is neither.  Free means on a set a die may touch
(:meth:`Workpiece.contact_sets`).

Each history row of a die scene keeps the narrowest wedge (``wedge_*``), the narrowest
pocket (``pocket_*``) and the narrower of the two (``fold_*``, ``fold_kind`` a
:class:`FoldKind`).  A *fold* is a run of rows whose angle stays below
``output.lap_angle_deg`` at one place (:func:`folds`); a **lap** is a wedge fold that
persists to the run's end (:func:`laps`), a **pocket** likewise (:func:`pockets`).
Host NumPy, after the run (the design objective :class:`jaxform.design.objectives.
LapPenalty` is the differentiable wedge measure).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from enum import IntEnum

import numpy as np

# a flank of a wedge ends where the surface has turned away from the wedge by this much
# (deg): the mouth of a V-notch (turning by 90 - half its angle onto a flat face), the rim
# of a face folded over; a flank that curves gently (a barrel) runs on
FLANK_TURN_DEG = 45.0

# a fold that moves farther than this plus twice the stroke between two rows is another
# fold (mm): the material at a fold moves with the dies
FOLD_JUMP_MM = 0.1


class FoldKind(IntEnum):
    """The history's ``fold_kind``: which measure the narrowest ``fold_*`` is."""

    NONE = 0
    WEDGE = 1
    POCKET = 2


@dataclass(frozen=True)
class Wedge:
    """The narrowest wedge of a surface: air-side angle (deg; 180 where there is none), the
    root (mm), the depth (mm, the shorter flank)."""

    angle_deg: float = 180.0
    r_mm: float = float("nan")
    z_mm: float = float("nan")
    depth_mm: float = 0.0


@dataclass(frozen=True)
class Pocket:
    """The narrowest pocket of a surface: atan(gap / half length) (deg; 180 where there is
    none), the largest gap to the die (mm) and where it is, the length along the surface."""

    angle_deg: float = 180.0
    gap_mm: float = 0.0
    length_mm: float = 0.0
    r_mm: float = float("nan")
    z_mm: float = float("nan")


@dataclass(frozen=True)
class SurfaceFolds:
    """A surface's narrowest wedge and narrowest pocket."""

    wedge: Wedge
    pocket: Pocket

    @property
    def kind(self) -> FoldKind:
        if min(self.wedge.angle_deg, self.pocket.angle_deg) >= 180.0:
            return FoldKind.NONE
        return FoldKind.POCKET if self.pocket.angle_deg < self.wedge.angle_deg else FoldKind.WEDGE

    def narrowest(self) -> tuple[float, float, float, float]:
        """(angle deg, r, z, depth mm) of the narrower of the two (a pocket's depth: its
        length); (180, nan, nan, 0) where there is neither."""
        if self.pocket.angle_deg < self.wedge.angle_deg:
            p = self.pocket
            return p.angle_deg, p.r_mm, p.z_mm, p.length_mm
        w = self.wedge
        return w.angle_deg, w.r_mm, w.z_mm, w.depth_mm


def _flank(pts, free_out, touching, turn, root: int, step: int) -> float:
    """Length (mm) of the flank from vertex ``root`` walking by ``step`` (+1 forward, -1
    back) along the loop: it stops after an edge that reaches a die, before an edge off the
    free surface, or at the vertex where its net turn away from the wedge (a positive turn
    of the counter-clockwise loop, whichever way it is walked) passes FLANK_TURN_DEG."""
    n = len(pts)
    length, turned, j = 0.0, 0.0, root
    for _ in range(n - 1):
        k = (j + step) % n
        if not free_out[j if step > 0 else k]:
            break
        length += float(np.linalg.norm(pts[k] - pts[j]))
        j = k
        turned += turn[j]
        if touching[j] or turned > np.radians(FLANK_TURN_DEG):
            break
    return length


def surface_folds(pts: np.ndarray, free_out: np.ndarray, gap: np.ndarray,
                  touch_mm: float) -> SurfaceFolds:  # fmt: skip
    """The narrowest wedge and pocket (module docstring) of a section's boundary.

    pts: (n, 2) the boundary as one counter-clockwise loop (material on the left);
    free_out: (n,) whether the edge pts[i] -> pts[i + 1] is on the free surface; gap: (n,)
    each vertex's gap to the nearest die (mm; inf where there is none); touch_mm: the gap
    at or below which a vertex touches a die."""
    n = len(pts)
    free_in = np.roll(free_out, 1)
    touching = gap <= touch_mm
    e_in = pts - np.roll(pts, 1, axis=0)
    e_out = np.roll(pts, -1, axis=0) - pts
    turn = np.arctan2(
        e_in[:, 0] * e_out[:, 1] - e_in[:, 1] * e_out[:, 0], np.sum(e_in * e_out, axis=1)
    )
    angle = np.where(free_in & free_out & ~touching, np.degrees(np.pi + turn), np.inf)
    wedge = Wedge()
    k = int(np.argmin(angle))
    if np.isfinite(angle[k]):
        depth = min(_flank(pts, free_out, touching, turn, k, s) for s in (1, -1))
        wedge = Wedge(float(angle[k]), float(pts[k, 0]), float(pts[k, 1]), depth)
    length = np.linalg.norm(e_out, axis=1)
    pocket = Pocket()
    for i in np.nonzero(touching & free_out & ~np.roll(touching, -1))[0]:
        run, j = [], (i + 1) % n  # the free vertices after the touching vertex i
        while not touching[j] and free_in[j] and len(run) < n:
            run.append(j)
            j = (j + 1) % n
        if not run or not touching[j] or not free_in[j]:
            continue  # the run ends off the free surface (axis, mid-plane): no pocket
        span = float(sum(length[m] for m in [i, *run]))
        k = max(run, key=lambda m: gap[m])
        a = float(np.degrees(np.arctan2(gap[k], 0.5 * span)))
        if a < pocket.angle_deg:
            pocket = Pocket(a, float(gap[k]), span, float(pts[k, 0]), float(pts[k, 1]))
    return SurfaceFolds(wedge, pocket)


def scene_folds(scene, pos: np.ndarray, t: float) -> SurfaceFolds:
    """:func:`surface_folds` of a scene's section at nodal positions ``pos`` and time t,
    against its dies (no pocket without one)."""
    from jaxform.contact import TOUCH_GAP_MM
    from jaxform.mesh import boundary_polygon
    from jaxform.rezone import gap_function

    free_sets = set(scene.workpiece.contact_sets(scene.mesh))
    pts, labels, _ = boundary_polygon(scene.mesh, pos)
    free_out = np.array([lab in free_sets for lab in labels])
    gap = np.full(len(pts), np.inf)
    if scene.inputs.die is not None and free_out.any():
        gap = np.asarray(gap_function(scene.inputs.die, t)(pts)[0])
    return surface_folds(pts, free_out, gap, TOUCH_GAP_MM)


def fold_angle(scene, pos: np.ndarray, t: float) -> tuple[float, float, float, float]:
    """(angle deg, r, z, depth mm) of the narrower of the wedge and the pocket
    (:meth:`SurfaceFolds.narrowest`) of a scene at ``pos`` and t."""
    return scene_folds(scene, pos, t).narrowest()


def fold_columns(scene, pos: np.ndarray, times: np.ndarray) -> dict[str, np.ndarray]:
    """The history's fold columns for nodal positions ``pos`` (rows, n, 2) at ``times``:
    ``fold_angle_deg``, ``fold_r_mm``, ``fold_z_mm``, ``fold_depth_mm`` and ``fold_kind``
    (the narrower), ``wedge_angle_deg``, ``wedge_r_mm``, ``wedge_z_mm``,
    ``wedge_depth_mm``, ``pocket_angle_deg``, ``pocket_gap_mm``, ``pocket_length_mm``,
    ``pocket_r_mm``, ``pocket_z_mm``."""
    return columns([scene_folds(scene, p, t) for p, t in zip(pos, times)])


def columns(rows: list[SurfaceFolds]) -> dict[str, np.ndarray]:
    """The fold columns (:func:`fold_columns`) of one :class:`SurfaceFolds` per row."""
    narrow = np.array([f.narrowest() for f in rows], dtype=float).reshape(-1, 4)
    out = {f"fold_{k}": narrow[:, c]
           for c, k in enumerate(("angle_deg", "r_mm", "z_mm", "depth_mm"))}  # fmt: skip
    for prefix, cls in (("wedge", Wedge), ("pocket", Pocket)):
        for f in fields(cls):
            out[f"{prefix}_{f.name}"] = np.array(
                [getattr(getattr(row, prefix), f.name) for row in rows], dtype=float
            )
    out["fold_kind"] = np.array([int(f.kind) for f in rows], dtype=float)
    return out


@dataclass(frozen=True)
class Track:
    """Which history columns a fold is followed in: ``{prefix}_angle_deg``, ``_r_mm`` and
    ``_z_mm``, and ``{prefix}_{name}`` for each name in ``at_end`` (reported at the fold's
    last row; 0 where the history has no such column)."""

    prefix: str
    at_end: tuple[str, ...]


NARROWEST = Track("fold", ("depth_mm",))
WEDGES = Track("wedge", ("depth_mm",))
POCKETS = Track("pocket", ("gap_mm", "length_mm"))


def folds(history: dict, angle_deg: float, track: Track = NARROWEST) -> list[dict]:
    """Every fold of a run in one measure (``track``): a run of consecutive rows whose angle
    is below ``angle_deg`` at one place (its point moving less than FOLD_JUMP_MM plus twice
    the stroke from row to row: one narrower elsewhere starts another fold).  Each: its
    first row, stroke, place and angle there; its last row, angle and the ``at_end``
    columns there; whether it persists to the run's last row."""
    p = track.prefix
    a = np.asarray(history.get(f"{p}_angle_deg", []))
    if angle_deg <= 0.0 or not len(a):
        return []
    where = np.column_stack([history[f"{p}_r_mm"], history[f"{p}_z_mm"]])
    ends = {c: np.asarray(history.get(f"{p}_{c}", np.zeros(len(a)))) for c in track.at_end}
    stroke = np.asarray(history["stroke_mm"])
    out, start = [], None
    for k in range(len(a) + 1):
        on = k < len(a) and a[k] < angle_deg
        near = FOLD_JUMP_MM + 2.0 * abs(stroke[min(k, len(a) - 1)] - stroke[k - 1])
        same = on and start is not None and np.linalg.norm(where[k] - where[k - 1]) < near
        if start is not None and not same:  # the fold from start ends at row k - 1
            end = k - 1
            out.append(dict(row=start, stroke_mm=float(stroke[start]),
                            r_mm=float(where[start, 0]), z_mm=float(where[start, 1]),
                            angle_deg=float(a[start]), last_row=end,
                            end_r_mm=float(where[end, 0]), end_z_mm=float(where[end, 1]),
                            end_angle_deg=float(a[end]),
                            **{c: float(v[end]) for c, v in ends.items()},
                            persists=end == len(a) - 1))  # fmt: skip
            start = None
        if on and start is None:
            start = k
    return out


def laps(history: dict, angle_deg: float) -> list[dict]:
    """The laps of a run: the wedge folds (:func:`folds` of ``wedge_*``) that persist to its
    end, each with its depth (``depth_mm``) at the end.  A wedge that closes below
    ``angle_deg`` and opens again is no lap; a pocket is never one (:func:`pockets`)."""
    return [f for f in folds(history, angle_deg, WEDGES) if f["persists"]]


def pockets(history: dict, angle_deg: float) -> list[dict]:
    """The pockets of a run that persist to its end (:func:`folds` of ``pocket_*``): air
    trapped between the material and a die, closed at both ends by material on the die
    (underfill along the die wall), each with its gap (``gap_mm``) and length
    (``length_mm``) at the end.  A pocket whose contact fronts meet before the end (the
    material filling against the die) is gone by then and is not reported."""
    return [f for f in folds(history, angle_deg, POCKETS) if f["persists"]]
