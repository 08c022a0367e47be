"""Material laws under one contract (see :mod:`jaxform.materials.base`)."""

from jaxform.materials.anand import Anand, AnandParams
from jaxform.materials.base import MaterialState
from jaxform.materials.elastic import ElasticParams, Hypoelastic
from jaxform.materials.j2 import J2Params, J2Plasticity
from jaxform.materials.presets import load_material, load_thermal_properties, material_from_table

__all__ = [
    "Anand",
    "AnandParams",
    "ElasticParams",
    "Hypoelastic",
    "J2Params",
    "J2Plasticity",
    "MaterialState",
    "load_material",
    "load_thermal_properties",
    "material_from_table",
]
