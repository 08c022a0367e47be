"""The whole document: the sections in their order (:data:`SECTIONS`), the schema of
every key (:data:`SCHEMA`), which sections a workpiece takes, and the typed, frozen
:class:`Config` of a validated document (:func:`typed`).  This module imports no JAX."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from jaxform.config.die_sections import (
    FRICTION_COEFFICIENT,
    FRICTION_DIES,
    BottomDieConfig,
    DieConfig,
    DieFrictionConfig,
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

_BEFORE_FRICTION = (BilletConfig, RingConfig, BlockConfig, MembraneConfig, LoadConfig, MeshConfig,
                    RemeshConfig, MaterialConfig, DieConfig, PressConfig, BottomDieConfig,
                    SideDieConfig, FrictionConfig)  # fmt: skip
_AFTER_FRICTION = (WearConfig, ThermalConfig, TimeConfig, SolverConfig, OutputConfig,
                   DesignConfig, StudyConfig)  # fmt: skip
# every section class under its TOML name, in the order of the documents and the
# reference; a die's friction table ("die.friction") is a section of its own here
SECTIONS: dict[str, type] = {
    **{cls.section_name: cls for cls in _BEFORE_FRICTION},
    **{f"{die}.friction": DieFrictionConfig for die in FRICTION_DIES},
    **{cls.section_name: cls for cls in _AFTER_FRICTION},
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
    # the dies' own friction tables ([die.friction] etc.; None outside a die scene)
    die_friction: DieFrictionConfig | None = None
    bottom_die_friction: DieFrictionConfig | None = None
    side_die_friction: DieFrictionConfig | None = None
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
            if (sec := getattr(self, _attribute(name))) is not None
        }

    def friction_key(self, die: str, coefficient: str) -> str:
        """The config key that sets ``coefficient`` (mu or m) of die section ``die``."""
        return friction_source(self.to_dict(), die, coefficient)

    def friction_of(self, die: str) -> FrictionConfig:
        """The friction law of die section ``die`` (of FRICTION_DIES): its own table's
        keys over [friction]'s (:func:`die_friction`)."""
        return FrictionConfig(**die_friction(self.to_dict(), die))

    def die_sections(self) -> tuple[str, ...]:
        """The die sections that build a die (:func:`friction_dies`)."""
        return friction_dies(self.to_dict())


def _attribute(section_name: str) -> str:
    """The :class:`Config` attribute of a section ('die.friction' -> 'die_friction')."""
    return section_name.replace(".", "_")


def die_friction(cfg: dict, die: str) -> dict:
    """The friction keys (model, mu, m) of die section ``die`` in a validated document:
    each from its [<die>.friction] table where given there, else from [friction]."""
    own = cfg.get(f"{die}.friction") or {}
    return {k: v if own.get(k) is None else own[k] for k, v in cfg["friction"].items()}


def friction_source(cfg: dict, die: str, coefficient: str) -> str:
    """The config key that sets ``coefficient`` (mu or m) of die section ``die``."""
    own = cfg.get(f"{die}.friction") or {}
    return f"{die}.friction.{coefficient}" if own.get(coefficient) is not None else (
        f"friction.{coefficient}")  # fmt: skip


def friction_keys(cfg: dict) -> set[str]:
    """The config keys that set a coefficient of some die's friction law in a validated
    die scene (e.g. {'friction.m'}, {'friction.mu', 'side_die.friction.m'})."""
    out = set()
    for die in friction_dies(cfg):
        coefficient = FRICTION_COEFFICIENT.get(die_friction(cfg, die)["model"])
        if coefficient:
            out.add(friction_source(cfg, die, coefficient))
    return out


def friction_dies(cfg: dict) -> tuple[str, ...]:
    """The die sections of a validated die scene that build a die: the top die, the
    bottom die of a full-height workpiece, a side die with a profile."""
    piece = next((cfg[w] for w in ("billet", "ring") if w in cfg), {})
    full = piece.get("full_height", False)
    side = bool(cfg.get("side_die", {}).get("profile_mm"))
    return ("die",) + (("bottom_die",) if full else ()) + (("side_die",) if side else ())


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
            _attribute(name): SECTIONS[name](**{k: freeze(v) for k, v in table.items()})
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
    section = section.split(".")[0]  # a die's friction table goes with its die
    if section in WORKPIECES:
        return section == kind
    if section in _DIE_SECTIONS:
        return kind != "membrane"
    if section in _FORGING_SECTIONS:
        return kind in ("billet", "ring")
    if section in _LOAD_SECTIONS:
        return kind == "membrane"
    return True
