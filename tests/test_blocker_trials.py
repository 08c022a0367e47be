"""The blocker trials' configs (experiments/blocker_trials.py): a shape given where the die
ends must be the die the written process runs, starting where the configured one started,
and a raised later die must keep its end; checked on the disk design's document, whose
numbers are known (blocker from z = 3.3 mm at the axis, 1.7 mm of travel; finisher to a
0.8 mm final gap)."""

import copy
import tomllib

import numpy as np
import pytest
import tomli_w
from experiment_loader import ROOT, experiment

from jaxform.process_config import load_typed

CONFIG = ROOT / "experiments" / "two_stage_disk_design.toml"


@pytest.fixture(scope="module")
def trials():
    with pytest.MonkeyPatch.context() as mp:
        mp.syspath_prepend(str(ROOT / "experiments"))  # it imports billet_volume_sweep
        yield experiment("blocker_trials")


@pytest.fixture(scope="module")
def doc():
    with open(CONFIG, "rb") as fh:
        d = tomllib.load(fh)
    d.pop("design")
    return d


def test_a_shape_is_the_die_at_its_end_from_the_configured_start(trials, doc, tmp_path):
    name, end = trials.parse_shape("mini=0,1.2;4.2,1.2;4.5,2.6;5.9,2.6;6.25,0.6;12,0.6")
    assert name == "mini" and end.shape == (6, 2)
    new = trials.with_shape(doc, "blocker", end, {"finisher": 0.5})
    ops = trials.operations(new)
    blocker, finisher = ops["blocker"], ops["finisher"]
    assert blocker["travel_mm"] == pytest.approx(3.3 - 1.2, abs=1e-12)
    start = np.asarray(blocker["die"]["profile_mm"])
    np.testing.assert_allclose(start - [0.0, blocker["travel_mm"]], end, atol=1e-12)
    assert start[0, 1] == pytest.approx(3.3, abs=1e-12)  # the same start at the axis
    fin0 = np.asarray(trials.operations(doc)["finisher"]["die"]["profile_mm"])
    np.testing.assert_allclose(np.asarray(finisher["die"]["profile_mm"]), fin0 + [0, 0.5])
    assert finisher["final_gap_mm"] == 0.8  # its end stays
    # the document given is left as it was, and the written one is a valid process
    assert trials.operations(doc)["blocker"]["travel_mm"] == 1.7
    path = tmp_path / "mini.toml"
    path.write_text(tomli_w.dumps(new))
    process = load_typed(path)
    assert [op.name for op in process.operations][:3] == ["blocker", "transfer", "finisher"]


def test_the_configured_shape_writes_the_configured_process(trials, doc):
    ops = trials.operations(doc)
    end = np.asarray(ops["blocker"]["die"]["profile_mm"]) - [0.0, 1.7]
    same = trials.with_shape(doc, "blocker", end, {})
    blocker = trials.operations(same)["blocker"]
    assert blocker["travel_mm"] == pytest.approx(1.7, abs=1e-12)
    np.testing.assert_allclose(blocker["die"]["profile_mm"], ops["blocker"]["die"]["profile_mm"])
    rest = [copy.deepcopy(d) for d in (same, doc)]
    for d in rest:  # nothing else changed
        trials.operations(d)["blocker"]["die"].pop("profile_mm")
        trials.operations(d)["blocker"].pop("travel_mm")
    assert rest[0] == rest[1]


@pytest.mark.parametrize("text", ["=0,1;1,1", "a=0,1", "a=0,1;x,2", "a=1,1;0,1"])
def test_a_shape_that_is_no_profile_is_refused(trials, text):
    with pytest.raises(SystemExit, match="--shape"):
        trials.parse_shape(text)


def test_a_shape_above_the_die_start_is_refused(trials, doc):
    with pytest.raises(SystemExit, match="not below the die's start"):
        trials.with_shape(doc, "blocker", np.array([[0.0, 3.4], [12.0, 3.4]]), {})
