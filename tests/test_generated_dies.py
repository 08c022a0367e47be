"""Generated closed dies (jaxform.generated_dies): valid, clear of their billets, with the
volume they promise; and (slow) a few of them run to the end with the library's defaults.

References: the billet's volume is (1 + excess) x the part cavity's (pi (R_p^2 h_f +
r_hub^2 d_hub), sharp corners) to 1e-12; the travel brings the flange face from the
billet's top to the flange's half thickness, to 1e-12.
"""

import math

import numpy as np
import pytest

import jaxform
from jaxform.config import load_config, typed
from jaxform.generated_dies import draw, flanged_hub, profile
from jaxform.scenes import build_scene

SEEDS = range(40)


@pytest.mark.parametrize("seed", SEEDS)
def test_generated_die_is_a_valid_scene_clear_of_its_billet(seed):
    """Each seed's config validates (every key in range), builds a scene (which refuses a
    die that overlaps the billet at t = 0), gets the closed-die remeshing default, and
    holds the volume and travel it was drawn for."""
    jaxform.enable_x64()
    f = draw(seed)
    doc = flanged_hub(seed)
    cfg = load_config(doc)
    assert cfg["remesh"]["quality_below"] == 0.3  # a closed die remeshes by default
    scene = build_scene(typed(cfg))
    h_b = doc["billet"]["height_mm"] / 2.0
    v_billet = math.pi * (doc["billet"]["diameter_mm"] / 2.0) ** 2 * h_b
    assert v_billet == pytest.approx((1.0 + f.excess) * f.cavity_volume_mm3, rel=1e-12)
    assert doc["die"]["reduction"] * h_b == pytest.approx(h_b - f.flange, rel=1e-12)
    # die.speed_mm_s closes the two halves: the modelled half travels at half of it
    assert scene.t_end == pytest.approx(2.0 * (h_b - f.flange) / 0.1, rel=1e-9)
    pts = np.asarray(profile(f))
    assert np.all(np.diff(pts[:, 0]) >= 0.0)  # walked outward from the axis
    assert f.billet_radius < f.part_radius - 1.0  # the billet starts clear of the wall
    # the die starts 1 um above the billet top: the flange face at z = h_b + 1e-3 mm
    assert pts[2, 1] == pytest.approx(h_b + 1e-3, abs=1e-6)  # written to 1e-6 mm


def test_generated_dies_vary():
    """The draws cover the issue's ranges: both friction laws, with and without a gutter,
    billet radii over 4-6 mm."""
    fs = [draw(s) for s in SEEDS]
    assert {f.friction for f in fs} == {"shear", "coulomb"}
    assert {(f.friction, f.coefficient_key) for f in fs} == {("shear", "m"), ("coulomb", "mu")}
    assert {f.gutter for f in fs} == {True, False}
    radii = [f.billet_radius for f in fs]
    assert 4.0 <= min(radii) < 4.3 and 5.7 < max(radii) <= 6.0


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 3])
def test_generated_die_runs_to_the_end_with_the_defaults(seed):
    """Seeds 0 and 3 (Coulomb 0.27 with a gutter; shear 0.23 without) with nothing but the
    generated config: they reach the end of the stroke, remeshing on the closed-die
    default, the cavity >= 99 % full (measured 99.4 and 99.85 %)."""
    res = jaxform.run(flanged_hub(seed), ["output.plots=false", "output.fields=false"])
    h = res.history
    assert res.remeshes
    assert h["time_s"][-1] == pytest.approx(res.scene.t_end, rel=1e-12)
    assert h["die_fill"][-1] >= 0.99
