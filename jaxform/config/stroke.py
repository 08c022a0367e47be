"""When the dies have closed: the end time of a run driven by the ram speed or by path
tables, one implementation for the config's step-count check (from the configured
height) and for the scene's die motion (:mod:`jaxform.scenes`, from the mesh's height).

Plain Python floats, the same operations in the same order as NumPy's ``interp`` and
``searchsorted``, so a path table inverted here gives the scene the same end time to
the last bit.  This module imports no JAX (nor NumPy)."""

from __future__ import annotations

from bisect import bisect_left, bisect_right
from collections.abc import Sequence

from jaxform.config.die_sections import BottomDieConfig, DieConfig
from jaxform.errors import ConfigError

# a bottom die without a path table stands: its rise is 0 at every time
_STANDING = ((0.0, 1.0), (0.0, 0.0))


def travel_at(times: Sequence[float], travel: Sequence[float], t: float) -> float:
    """A path table's travel at time ``t`` (mm): linear between its rows, constant past
    its ends (``numpy.interp``)."""
    if t < times[0]:
        return float(travel[0])
    if t >= times[-1]:
        return float(travel[-1])
    j = bisect_right(times, t) - 1
    if t == times[j]:
        return float(travel[j])
    slope = (travel[j + 1] - travel[j]) / (times[j + 1] - times[j])
    return float(slope * (t - times[j]) + travel[j])


def time_at_travel(
    times: Sequence[float], travel: Sequence[float], target_mm: float, key: str
) -> float:
    """The time (s) at which a non-decreasing path table first reaches ``target_mm``;
    ConfigError naming ``key`` where it never does."""
    if target_mm > travel[-1] + 1e-12:
        raise ConfigError(
            f"{key}: the path ends at travel {travel[-1]:g} mm, before the required "
            f"{target_mm:g} mm"
        )
    k = max(bisect_left(travel, target_mm - 1e-12), 1)
    t0, t1, d0, d1 = times[k - 1], times[k], travel[k - 1], travel[k]
    return float(t0 + (target_mm - d0) * (t1 - t0) / (d1 - d0)) if d1 > d0 else float(t1)


def closure_table(
    die: DieConfig, bottom: BottomDieConfig | None
) -> tuple[tuple[float, ...], tuple[float, ...], str]:
    """(times, how far the dies have closed at them, the keys of the table) of the path
    tables: the top die's, plus the bottom die's rise where ``bottom`` is given (a
    full-height scene; a bottom die without a table stands), on the union of the times."""
    top = (die.path_time_s, die.path_travel_mm)
    if bottom is None:
        return *top, "die.path_travel_mm"
    rise = (bottom.path_time_s, bottom.path_travel_mm) if bottom.path_time_s else _STANDING
    times = tuple(sorted(set(top[0]) | set(rise[0])))
    closure = tuple(travel_at(*top, t) + travel_at(*rise, t) for t in times)
    return times, closure, "die.path_travel_mm + bottom_die.path_travel_mm"


def closing_time(
    die: DieConfig, bottom: BottomDieConfig | None, target_mm: float, share: float
) -> float:
    """The time (s) at which the dies have closed by ``target_mm``: along the path tables
    (:func:`closure_table`; ``bottom`` for a full-height scene, else None), or at
    ``share`` x die.speed_mm_s (the moving die's share of the ram speed: 1/2 for the top
    die of a half-height model, else 1).  ConfigError where the tables stop short."""
    if die.path_time_s:
        times, closure, keys = closure_table(die, bottom)
        return time_at_travel(times, closure, target_mm, keys)
    return target_mm / (share * die.speed_mm_s)
