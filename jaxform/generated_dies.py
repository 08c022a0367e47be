"""Closed dies nobody tuned: seeded flanged-hub forgings with a flash land, as configs.

:func:`flanged_hub` draws one axisymmetric closed-die forging from a seed and returns its
config document (a nested dict that :func:`jaxform.config.load_config` reads, or that
:func:`write_config` writes as TOML), the way a user would bring a die of their own: a
billet of Al 1100-O at 673 K, the upper half modelled (both die halves alike), shear or
Coulomb friction, a q1p0 10 x 10 mesh, and the library's defaults for everything else.

The die is drawn at the end of its stroke and moved up by its travel, walked from the
axis outward with the billet below: the hub recess roof (radius ``hub_radius``, depth
``hub_depth`` above the flange face), the flange face (half thickness ``flange``), the
part's wall at ``part_radius`` down to the flash land (half gap ``flash_gap``, width
``land_width``), and either a gutter (its roof ``gutter_depth`` above the land) or the
land running on.  The billet (radius ``billet_radius``) holds ``1 + excess`` times the
part's cavity (the recess and the flange of the upper half, rounded corners ignored), so
the excess escapes under the land as flash.  The travel brings the flange face from the
billet's top down to ``flange``: ``die.reduction`` = travel / billet half height.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np


@dataclass(frozen=True)
class FlangedHub:
    """The drawn dimensions of one generated forging (mm, and the friction)."""

    seed: int
    billet_radius: float
    hub_radius: float
    hub_depth: float
    flange: float
    part_radius: float
    land_width: float
    flash_gap: float
    gutter: bool
    gutter_depth: float
    corner_radius: float
    excess: float
    friction: str  # the [friction] table's model
    coefficient_key: str  # the key of its coefficient in that table (mu or m)
    coefficient: float

    @property
    def cavity_volume_mm3(self) -> float:
        """The upper half's part cavity at the end of the stroke (sharp corners)."""
        return math.pi * (self.part_radius**2 * self.flange + self.hub_radius**2 * self.hub_depth)

    @property
    def billet_half_height(self) -> float:
        return (1.0 + self.excess) * self.cavity_volume_mm3 / (math.pi * self.billet_radius**2)

    @property
    def travel(self) -> float:
        return self.billet_half_height - self.flange


def draw(seed: int) -> FlangedHub:
    """The dimensions of forging ``seed``: billet radius 4-6 mm, part radius 1.25-1.6 x
    the billet's, hub radius 0.25-0.5 x the part's and depth 0.5-2 mm, flange half
    thickness 1.5-3 mm, flash half gap 0.3-0.6 mm, land 0.6-1.5 mm wide, a gutter 1-2 mm
    deep in two of three dies, corner radii 0.2-0.5 mm, excess volume 5-15 %, shear
    factor 0.1-0.4 or Coulomb 0.1-0.3."""
    rng = np.random.default_rng(seed)
    u = rng.uniform
    billet_radius = u(4.0, 6.0)
    part_radius = billet_radius * u(1.25, 1.6)
    coulomb = bool(rng.random() < 0.4)
    law = ("coulomb", "mu", (0.1, 0.3)) if coulomb else ("shear", "m", (0.1, 0.4))
    return FlangedHub(
        seed=seed,
        billet_radius=round(billet_radius, 3),
        hub_radius=round(part_radius * u(0.25, 0.5), 3),
        hub_depth=round(u(0.5, 2.0), 3),
        flange=round(u(1.5, 3.0), 3),
        part_radius=round(part_radius, 3),
        land_width=round(u(0.6, 1.5), 3),
        flash_gap=round(u(0.3, 0.6), 3),
        gutter=bool(rng.random() < 2.0 / 3.0),
        gutter_depth=round(u(1.0, 2.0), 3),
        corner_radius=round(u(0.2, 0.5), 3),
        excess=round(u(0.05, 0.15), 3),
        friction=law[0],
        coefficient_key=law[1],
        coefficient=round(u(*law[2]), 3),
    )


def profile(f: FlangedHub) -> list[list[float]]:
    """The top die's profile at the start (mm), from the axis outward: 1 um above the
    billet's top face."""
    lift = f.travel + 1e-3
    face, roof = f.flange + lift, f.flange + f.hub_depth + lift
    land = f.flash_gap + lift
    r_land = f.part_radius + f.land_width
    pts = [[0.0, roof], [f.hub_radius, roof], [f.hub_radius, face], [f.part_radius, face],
           [f.part_radius, land], [r_land, land]]  # fmt: skip
    outer = r_land + 3.0 * f.land_width + 4.0
    if f.gutter:
        pts += [[r_land, land + f.gutter_depth], [outer, land + f.gutter_depth]]
    else:
        pts += [[outer, land]]
    return [[round(r, 6), round(z, 6)] for r, z in pts]


def flanged_hub(seed: int) -> dict:
    """The config document of forging ``seed`` (:func:`draw`), library defaults elsewhere."""
    f = draw(seed)
    friction = {"model": f.friction, f.coefficient_key: f.coefficient}
    return {
        "billet": {"diameter_mm": 2.0 * f.billet_radius, "height_mm": 2.0 * f.billet_half_height},
        "mesh": {"nr": 10, "nz": 10, "element": "q1p0"},
        "material": {"preset": "al1100_673K"},
        "die": {
            "speed_mm_s": 0.1,
            "reduction": f.travel / f.billet_half_height,
            "closed": True,
            "part_radius_mm": f.part_radius,
            "corner_contact": True,
            "corner_radius_mm": f.corner_radius,
            "profile_mm": profile(f),
        },
        "friction": friction,
        "time": {"dt_s": 1.0},
        "solver": {"max_cutbacks": 8},
    }


def describe(seed: int) -> str:
    """One line: the drawn dimensions of forging ``seed``."""
    return ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}"
                     for k, v in asdict(draw(seed)).items())  # fmt: skip
