"""What each state field is indexed over, and maps of a state field by field.

A field of the simulation state (:class:`jaxform.stepping.SimState`) declares, in its
dataclass field's metadata (:func:`over`), what its values are indexed over:

* :data:`UNKNOWNS`: the unknown vector x (:class:`jaxform.assembly.Layout`: nodal fields,
  then the candidates' multipliers, then the corner facets');
* :data:`RATES`: a vector in the layout of x that is a rate of it (the predictor's);
* :data:`GAUSS`: the Gauss-point state (leading axes: element, Gauss point), whose
  deformation gradient is measured from the reference configuration;
* :data:`ELEMENT`: other fields with the element as leading axis (damage integrals);
* :data:`CANDIDATE`: a measure per contact candidate (accumulated slip);
* :data:`STATUS`: a category per contact candidate (contact status);
* :data:`SCALAR`: not indexed by the mesh (time, friction work, heat, die wear).

Every map of a state from one mesh (or size) to another goes through
:func:`map_state` with a :class:`FieldMap`, one method per kind: the padding to a
capacity bucket and back (:mod:`jaxform.capacity`), remeshing and rezoning
(:class:`jaxform.remesh.StateMap`).  A new field only declares its kind.

:data:`OUTPUT_FIELDS`: the per-step output fields (:func:`jaxform.stepping.step_outputs`)
that are indexed over the mesh, with their kinds.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, replace


@dataclass(frozen=True)
class Over:
    """What a field is indexed over; ``method`` names the :class:`FieldMap` method that
    maps it."""

    method: str


UNKNOWNS = Over("unknowns")
RATES = Over("rates")
GAUSS = Over("gauss")
ELEMENT = Over("element")
CANDIDATE = Over("candidate")
STATUS = Over("status")
SCALAR = Over("scalar")


def over(kind: Over) -> dict:
    """The dataclass field metadata that declares a field's kind."""
    return {"over": kind}


def kinds(state) -> dict:
    """{field name: kind} of a state dataclass's fields."""
    return {f.name: f.metadata["over"] for f in dataclasses.fields(state)}


class FieldMap:
    """A map of a state's fields by kind: each method takes a field's value and returns
    the mapped value.  Defaults: a scalar field carries over."""

    def scalar(self, value):
        return value


def map_state(state, fmap: FieldMap):
    """The state with each field mapped by ``fmap``'s method for the field's kind."""
    return replace(
        state,
        **{name: getattr(fmap, k.method)(getattr(state, name)) for name, k in kinds(state).items()},
    )


OUTPUT_FIELDS = {
    "x": UNKNOWNS,
    "stress": ELEMENT,
    "s": ELEMENT,
    "eqps": ELEMENT,
    "slip_mm": CANDIDATE,
    "contact_status": STATUS,
    "damage": ELEMENT,
}
