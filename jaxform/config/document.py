"""The whole document: the sections in their order (:data:`SECTIONS`), the schema of
every key (:data:`SCHEMA`), which sections a workpiece takes, and the typed, frozen
:class:`Config` of a validated document (:func:`typed`).  This module imports no JAX."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from jaxform.config.die_sections import (
    BottomDieConfig,
    DieConfig,
    FrictionConfig,
    PressConfig,
    SideDieConfig,
    ThermalConfig,
    WearConfig,
)
from jaxform.config.run_sections import (
    DesignConfig,
    OutputConfig,
    SolverConfig,
    StudyConfig,
    TimeConfig,
)
from jaxform.config.schema import Field, bound_lengths, schema_of
from jaxform.config.workpiece_sections import (
    BilletConfig,
    BlockConfig,
    LoadConfig,
    MaterialConfig,
    MembraneConfig,
    MeshConfig,
    RemeshConfig,
    RingConfig,
)
from jaxform.errors import ConfigError

# every section class under its TOML name, in the order of the documents and the reference
SECTIONS: dict[str, type] = {
    cls.section_name: cls
    for cls in (
        BilletConfig,
        RingConfig,
        BlockConfig,
        MembraneConfig,
        LoadConfig,
        MeshConfig,
        RemeshConfig,
        MaterialConfig,
        DieConfig,
        PressConfig,
        BottomDieConfig,
        SideDieConfig,
        FrictionConfig,
        WearConfig,
        ThermalConfig,
        TimeConfig,
        SolverConfig,
        OutputConfig,
        DesignConfig,
        StudyConfig,
    )
}
SCHEMA: dict[str, dict[str, Field]] = bound_lengths(
    {name: schema_of(cls) for name, cls in SECTIONS.items()}
)


@dataclass(frozen=True, kw_only=True)
class Config:
    """A validated scene config, typed and frozen: one attribute per section, None where
    the scene has no such section (a membrane has no die; a billet no load).  Built by
    :func:`typed` from :func:`load_config`'s document; :meth:`to_dict` gives it back."""

    billet: BilletConfig | None = None
    ring: RingConfig | None = None
    block: BlockConfig | None = None
    membrane: MembraneConfig | None = None
    load: LoadConfig | None = None
    mesh: MeshConfig
    remesh: RemeshConfig
    material: MaterialConfig
    die: DieConfig | None = None
    press: PressConfig | None = None
    bottom_die: BottomDieConfig | None = None
    side_die: SideDieConfig | None = None
    friction: FrictionConfig | None = None
    wear: WearConfig | None = None
    thermal: ThermalConfig
    time: TimeConfig
    solver: SolverConfig
    output: OutputConfig
    design: DesignConfig
    study: StudyConfig

    @property
    def workpiece(self) -> str:
        """The workpiece section's name: 'billet', 'ring', 'block' or 'membrane'."""
        return next(w for w in WORKPIECES if getattr(self, w) is not None)

    def to_dict(self) -> dict:
        """The TOML document (sections present, lists for tuples)."""
        return {
            name: {f.name: thaw(getattr(sec, f.name)) for f in dataclasses.fields(sec)}
            for name in SECTIONS
            if (sec := getattr(self, name)) is not None
        }


def freeze(value: Any) -> Any:
    """A TOML value with its lists as tuples (as the typed sections hold it)."""
    return tuple(freeze(v) for v in value) if isinstance(value, list) else value


def thaw(value: Any) -> Any:
    """A typed value with its tuples as lists (as the TOML document holds it)."""
    return [thaw(v) for v in value] if isinstance(value, tuple) else value


def typed(cfg: dict) -> Config:
    """The :class:`Config` of a document from :func:`load_config` (validated already)."""
    return Config(
        **{
            name: SECTIONS[name](**{k: freeze(v) for k, v in table.items()})
            for name, table in cfg.items()
        }
    )


# Exactly one workpiece section: a solid billet, a ring, an indented block (all pressed by
# a die) or a membrane (clamped, loaded by a traction; no die).
WORKPIECES = ("billet", "ring", "block", "membrane")
# sections that only some workpieces use
_DIE_SECTIONS = ("die", "press", "friction", "wear")
_FORGING_SECTIONS = ("bottom_die", "side_die")  # billets and rings only
_LOAD_SECTIONS = ("load",)


def workpiece_section(raw: dict) -> str:
    """The name of the one workpiece section of a document, or ConfigError."""
    given = [w for w in WORKPIECES if w in raw]
    if len(given) != 1:
        raise ConfigError(
            f"give exactly one workpiece section, "
            f"{', '.join(f'[{w}]' for w in WORKPIECES)} "
            f"(found {', '.join(given) or 'none'})"
        )
    return given[0]


def applies(section: str, kind: str) -> bool:
    """Whether a section belongs in a scene with workpiece ``kind``."""
    if section in WORKPIECES:
        return section == kind
    if section in _DIE_SECTIONS:
        return kind != "membrane"
    if section in _FORGING_SECTIONS:
        return kind in ("billet", "ring")
    if section in _LOAD_SECTIONS:
        return kind == "membrane"
    return True
