"""The assembly's terms and the state's declared fields.

References: the sparsity pattern is the unique set of the terms' blocks (each raw entry
of a term's k x k block over its dofs lands on the slot of that (row, col)); a scene
without a temperature field has no heat term; every state field declares its kind, so
padding a state to a capacity bucket and trimming it back gives the state again
exactly, and a state map onto the same mesh (a rezoning that moved no node) carries
every field as it is.
"""

from dataclasses import fields, replace
from pathlib import Path

import jax
import numpy as np
import pytest

from jaxform.assembly import (
    ElementTerm,
    FacetContact,
    FixedRows,
    HeatTerm,
    Load,
    NodeContact,
)
from jaxform.capacity import padded
from jaxform.config import load_config
from jaxform.fields import OUTPUT_FIELDS, kinds
from jaxform.scenes import build_scene
from jaxform.stepping import SimState, initial_state
from jaxform.transfer import StateMap, Transfer

ROOT = Path(__file__).resolve().parents[1]


def _scene(name, *over):
    return build_scene(
        load_config(ROOT / "configs" / f"{name}.toml", ["mesh.nr=3", "mesh.nz=3", *over])
    )


def _random_state(scene, seed=0):
    """The scene's initial state with every array field filled with random values (the
    contact status with random categories)."""
    rng = np.random.default_rng(seed)
    st = jax.tree_util.tree_map(np.asarray, initial_state(scene.model, scene.inputs))

    def fill(a):
        if a.dtype.kind == "i":
            return rng.integers(0, 3, a.shape).astype(a.dtype)
        return rng.standard_normal(a.shape)

    return jax.tree_util.tree_map(fill, st)


def test_pattern_is_the_terms_blocks():
    """Reference: the raw entries built from each term's dofs, in the terms' order."""
    sc = _scene("closed_die", "die.corner_contact=true")
    terms = sc.model.terms
    assert [type(t) for t in terms] == [ElementTerm, NodeContact, FacetContact, Load, FixedRows]
    host = jax.tree_util.tree_map(np.asarray, sc.idx)
    rows, cols, slot = host.rows, host.cols, host.slot
    start = 0
    for t in terms:
        dofs = np.asarray(t.dofs(host))
        k = dofs.shape[1] if dofs.size else 0
        n_raw = dofs.shape[0] * k * k
        s = slot[start : start + n_raw].reshape(dofs.shape[0], k, k)
        np.testing.assert_array_equal(rows[s], np.broadcast_to(dofs[:, :, None], s.shape))
        np.testing.assert_array_equal(cols[s], np.broadcast_to(dofs[:, None, :], s.shape))
        start += n_raw
    assert start == len(slot)
    assert len(np.unique(rows.astype(np.int64) * sc.model.layout.n_dofs + cols)) == len(rows)


def test_heat_is_a_term_only_with_a_temperature_field():
    """Reference: the element term of hot_upsetting wraps the isothermal mechanics."""
    hot = _scene("hot_upsetting")
    cold = _scene("hot_upsetting", 'thermal.model="none"')
    assert isinstance(hot.model.element, HeatTerm)
    assert hot.model.element.mechanics == cold.model.element
    assert isinstance(cold.model.element, ElementTerm)
    assert cold.model.element.temperatures(cold.model.layout, np.zeros(3), None) is None


def test_every_state_field_declares_its_kind():
    """Reference: the dataclass fields of SimState; the output fields are state fields'
    values (the same kinds)."""
    declared = kinds(SimState)
    assert set(declared) == {f.name for f in fields(SimState)}
    assert declared["x"] == OUTPUT_FIELDS["x"] and declared["damage"] == OUTPUT_FIELDS["damage"]


@pytest.mark.parametrize("name", ["hot_upsetting", "closed_die"])
def test_padding_and_trimming_give_the_state_back(name):
    """Reference: the state itself (padding and trimming copy values)."""
    sc = _scene(name)
    st = _random_state(sc)
    pad = padded(sc)
    big = pad.state(st)
    assert big.x.shape == (pad.scene.model.layout.n_dofs,)
    assert big.damage.shape[0] == pad.scene.model.layout.n_elements
    back = jax.tree_util.tree_map(np.asarray, pad.trim(big))
    for a, b in zip(jax.tree_util.tree_leaves(st), jax.tree_util.tree_leaves(back), strict=True):
        np.testing.assert_array_equal(a, b)
    outs = {"x": np.asarray(big.x)[None], "damage": np.asarray(big.damage)[None],
            "slip_mm": np.asarray(big.slip_mm)[None]}  # fmt: skip
    trimmed = pad.trim_outputs(outs)
    np.testing.assert_array_equal(trimmed["x"][0], st.x)
    np.testing.assert_array_equal(trimmed["damage"][0], st.damage)
    np.testing.assert_array_equal(trimmed["slip_mm"][0], st.slip_mm)


def test_a_map_onto_the_same_mesh_carries_every_field():
    """Reference: the state with u = 0 and F = I (the new reference); the nodal fields,
    rates and multipliers the same to the interpolation's round-off (the new nodes are
    the old ones), the candidates' and the scalar fields exactly."""
    sc = _scene("hot_upsetting")
    st = _random_state(sc)
    lay, coords = sc.model.layout, np.asarray(sc.inputs.coords)
    x = st.x.copy()
    lay.nodal(x)[:, :2] = 0.0  # at the new reference
    st = replace(st, x=x, gauss=replace(st.gauss, F=np.broadcast_to(np.eye(3), st.gauss.F.shape)))
    elements = np.asarray(sc.mesh.elements)
    move = Transfer(coords, elements, coords, elements)
    new, new_coords = StateMap(lay, lay, move, np.zeros_like(coords)).apply(st, coords)
    np.testing.assert_allclose(new_coords, coords, atol=1e-12)
    np.testing.assert_allclose(new.x, st.x, atol=1e-12)
    np.testing.assert_allclose(new.x_rate, st.x_rate, atol=1e-12)
    for k in ("slip_mm", "contact_status", "t", "heat_mJ", "friction_work", "wear_mm"):
        np.testing.assert_array_equal(getattr(new, k), getattr(st, k))
    np.testing.assert_array_equal(new.gauss.F, st.gauss.F)


def test_a_new_mesh_starts_its_first_step_at_rest():
    """Reference: a remesh's map (one with a contact map: new candidates) sets the
    predictor's rates to 0, so the first step on the new mesh starts from the carried
    state (the old mesh's rates are not the new discretization's flow); its other fields
    carry as on a rezoning (here onto the same mesh: the unknowns to round-off)."""
    from jaxform.remesh import ContactMap

    sc = _scene("hot_upsetting")
    st = _random_state(sc, seed=1)
    lay, coords = sc.model.layout, np.asarray(sc.inputs.coords)
    elements = np.asarray(sc.mesh.elements)
    move = Transfer(coords, elements, coords, elements)
    n_c = lay.n_contact
    ends = np.column_stack([np.arange(n_c), np.arange(n_c)])
    w = np.column_stack([np.ones(n_c), np.zeros(n_c)])
    contact = ContactMap(ends, w, w, np.asarray(st.contact_status))
    new, _ = StateMap(lay, lay, move, np.zeros_like(coords), contact).apply(st, coords)
    assert n_c > 0 and np.abs(st.x_rate).max() > 0
    np.testing.assert_array_equal(new.x_rate, np.zeros(lay.n_dofs))
    np.testing.assert_allclose(lay.nodal(new.x)[:, 2:], lay.nodal(st.x)[:, 2:], atol=1e-12)
    kept, _ = StateMap(lay, lay, move, np.zeros_like(coords)).apply(st, coords)
    np.testing.assert_allclose(kept.x_rate, st.x_rate, atol=1e-12)
