"""The gradient-run checks of a validated document: the requirements that each design
group and objective declares (:mod:`jaxform.design.requirements`, where the one check
lives), applied to the document's typed sections.  This module imports no JAX."""

from __future__ import annotations

from collections.abc import Iterable

from jaxform.config.document import Config, typed
from jaxform.design import requirements
from jaxform.errors import ConfigError

# every design group and the objectives with a gradient through remeshes
GRADIENT_GROUPS = tuple(requirements.GROUPS)
REMESH_OBJECTIVES = tuple(n for n, o in requirements.OBJECTIVES.items() if o.through_remeshes)


def check_gradient_run(
    cfg: dict | Config, groups: Iterable[str] | None = None, where: str = "design.variables"
) -> None:
    """Refuse a validated config (a document from :func:`jaxform.config.load_config`, or
    its :class:`Config`) that a gradient run (jaxform design, taylor-test) cannot use,
    before anything is built: rezoning, design groups the scene lacks (``groups``: the
    groups asked for, ``where`` names the key or flag that asked; None = the scene's own),
    an objective whose inputs are missing."""
    requirements.check_gradient_run(cfg if isinstance(cfg, Config) else typed(cfg), groups, where)


def check_design_run(cfg: dict | Config) -> None:
    """:func:`check_gradient_run` for ``jaxform design``: the groups of design.variables."""
    c = cfg if isinstance(cfg, Config) else typed(cfg)
    if c.design.robust:
        raise ConfigError(
            f"design.robust = {c.design.robust!r}: a robust design is a process's so far (a "
            "config with [[process.operation]] tables)"
        )
    requirements.check_gradient_run(c, c.design.variables, "design.variables")
