"""TOML scene configs: load, override, validate and resolve defaults.

A scene is a two-level TOML document ``[section] key = value``. :data:`SCHEMA`
lists every allowed key with its type, default (``None`` = required), allowed
range or choices and a one-line description; keys carry their unit in the name.
:func:`load_config` returns a new nested dict with every key present, or raises
:class:`ConfigError` naming the full dotted key before anything else happens;
:func:`typed` gives its frozen :class:`Config`.  This package imports no JAX.

Modules: :mod:`~jaxform.config.schema` (Field, key(), section(), the size limits),
the section classes by theme (:mod:`~jaxform.config.workpiece_sections`,
:mod:`~jaxform.config.die_sections`, :mod:`~jaxform.config.run_sections`),
:mod:`~jaxform.config.document` (SECTIONS, SCHEMA, Config, typed),
:mod:`~jaxform.config.loading` (load_config, overrides, TOML in and out),
:mod:`~jaxform.config.rules` (the cross-key rules on the typed sections),
:mod:`~jaxform.config.stroke` (when the dies have closed: the end time, shared with the
scene) and :mod:`~jaxform.config.requirements` (the gradient-run checks).
"""

from jaxform.config.die_sections import (
    FRICTION_COEFFICIENT,
    FRICTION_DIES,
    FRICTION_MODELS,
    BottomDieConfig,
    DieConfig,
    DieFrictionConfig,
    FrictionConfig,
    PressConfig,
    SideDieConfig,
    ThermalConfig,
    WearConfig,
)
from jaxform.config.document import (
    SCHEMA,
    SECTIONS,
    WORKPIECES,
    Config,
    die_friction,
    friction_dies,
    friction_keys,
    friction_source,
    typed,
)
from jaxform.config.loading import (
    CLOSED_DIE_QUALITY,
    defaulted_sections,
    describe_schema,
    dump_config,
    given_sections,
    load_config,
    read_document,
    toml_form,
)
from jaxform.config.requirements import (
    GRADIENT_GROUPS,
    REMESH_OBJECTIVES,
    check_design_run,
    check_gradient_run,
)
from jaxform.config.rules import end_time
from jaxform.config.run_sections import (
    STUDY_PLANS,
    DesignConfig,
    OutputConfig,
    SolverConfig,
    StudyConfig,
    TimeConfig,
)
from jaxform.config.schema import (
    MAX_ELEMENTS,
    MAX_FORCE_N,
    MAX_LENGTH_MM,
    MAX_STEPS,
    Field,
    key,
    section,
)
from jaxform.config.workpiece_sections import (
    TRIGGERS,
    TRIGGERS_OFF,
    BilletConfig,
    BlockConfig,
    LoadConfig,
    MaterialConfig,
    MembraneConfig,
    MeshConfig,
    RemeshConfig,
    RingConfig,
    remesh_on,
)
from jaxform.errors import ConfigError

__all__ = [
    "Config",
    "ConfigError",
    "SECTIONS",
    "typed",
    "Field",
    "SCHEMA",
    "load_config",
    "dump_config",
    "toml_form",
    "describe_schema",
    "check_design_run",
    "check_gradient_run",
    "MAX_STEPS",
    "MAX_ELEMENTS",
    "MAX_LENGTH_MM",
    "MAX_FORCE_N",
    "CLOSED_DIE_QUALITY",
    "GRADIENT_GROUPS",
    "REMESH_OBJECTIVES",
    "STUDY_PLANS",
    "TRIGGERS",
    "TRIGGERS_OFF",
    "WORKPIECES",
    "FRICTION_COEFFICIENT",
    "FRICTION_DIES",
    "FRICTION_MODELS",
    "DieFrictionConfig",
    "die_friction",
    "friction_dies",
    "friction_keys",
    "friction_source",
    "defaulted_sections",
    "end_time",
    "given_sections",
    "key",
    "read_document",
    "remesh_on",
    "section",
    "BilletConfig",
    "BlockConfig",
    "BottomDieConfig",
    "DesignConfig",
    "DieConfig",
    "FrictionConfig",
    "LoadConfig",
    "MaterialConfig",
    "MembraneConfig",
    "MeshConfig",
    "OutputConfig",
    "PressConfig",
    "RemeshConfig",
    "RingConfig",
    "SideDieConfig",
    "SolverConfig",
    "StudyConfig",
    "ThermalConfig",
    "TimeConfig",
    "WearConfig",
]
