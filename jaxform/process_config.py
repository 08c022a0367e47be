"""The ``[[process.operation]]`` tables of a config: a multi-stage process, validated.

A process is an ordered list of operations, each a TOML table of the array
``[[process.operation]]`` with a ``kind``:

* ``forming``: a blow between its own dies.  Its tables ``die``, ``bottom_die``,
  ``friction``, ``time``, ``remesh``, ``press`` and ``thermal`` are the config's sections of
  those names, key by key over the base config's (so an operation writes only what differs);
  its stroke is ``die.reduction`` (of the workpiece's initial height), ``travel_mm`` (how
  far the dies close) or ``final_gap_mm`` (the smallest gap between the dies, or between the top
  die and the mid-plane of a half-height model, doubled, at the end);
* ``dwell``: ``time_s`` in air (convection and radiation with thermal.model = "coupled";
  without heat it only advances the clock);
* ``trim``: the material beyond ``radius_mm`` is cut off (the flash);
* ``reheat``: ``time_s`` in a furnace at ``furnace_temperature_K``, or the whole part set to
  ``set_temperature_K``.

:func:`load_document` reads a config with or without a process: without one it is exactly
:func:`jaxform.config.load_config`; with one the document gets a ``process`` entry, the list
of the validated operations (each forming operation with its merged sections validated by
``load_config`` as a scene of its own).  Every refusal is one line naming the operation
(``process.operation[2] (finisher)``) and the key.  This module imports no JAX.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from os import PathLike
from typing import Any

from jaxform.config.die_sections import FRICTION_COEFFICIENT
from jaxform.config.document import Config, typed
from jaxform.config.loading import load_config, parse_override, read_toml
from jaxform.config.schema import check_value, key, schema_of
from jaxform.design import requirements
from jaxform.errors import ConfigError

KINDS = ("forming", "dwell", "trim", "reheat")
# the sections a forming operation may give, key by key over the base config's
OPERATION_SECTIONS = ("die", "bottom_die", "friction", "time", "remesh", "press", "thermal")
# thermal keys that belong to the whole process (the temperature the unknown counts from)
PROCESS_THERMAL_KEYS = ("model", "billet_temperature_K")


@dataclass(frozen=True, kw_only=True)
class FormingOperation:
    """[[process.operation]] kind = "forming": a blow between the operation's dies."""

    name: str = key("", doc="the operation's name in the history and the plots ('' = its kind)")
    travel_mm: float | None = key(
        low=0.0,
        low_open=True,
        doc="how far the dies close in this operation (mm; half height: the top die's "
        "travel) (instead of die.reduction)",
    )
    final_gap_mm: float | None = key(
        low=0.0,
        doc="the smallest gap between the dies at the end (mm; half height: twice the top "
        "die's height above the mid-plane) (instead of die.reduction)",
    )


@dataclass(frozen=True, kw_only=True)
class DwellOperation:
    """[[process.operation]] kind = "dwell": the part waits in air (a transfer)."""

    name: str = key("", doc="the operation's name ('' = its kind)")
    time_s: float = key(low=0.0, low_open=True, high=1e5, doc="time in air (s)")
    dt_s: float | None = key(
        low=0.0, low_open=True, doc="largest time step of the dwell (s; default time.dt_s)"
    )
    air_temperature_K: float | None = key(
        low=1.0, high=5000.0, doc="air temperature (K; default thermal.air_temperature_K)"
    )
    htc_air_W_m2K: float | None = key(
        low=0.0, high=1e7, doc="convection coefficient (W/m^2 K; default thermal.htc_air_W_m2K)"
    )
    emissivity: float | None = key(
        low=0.0, high=1.0, doc="emissivity of the surface (default thermal.emissivity)"
    )


@dataclass(frozen=True, kw_only=True)
class TrimOperation:
    """[[process.operation]] kind = "trim": the material beyond a radius is cut off."""

    name: str = key("", doc="the operation's name ('' = its kind)")
    radius_mm: float = key(
        low=0.0, low_open=True, doc="the trim radius (mm): the material beyond it is removed"
    )
    element_size_mm: float = key(
        0.0,
        low=0.0,
        doc="element size of the kept part's new mesh (mm; 0 = the mean of the incoming mesh)",
    )


@dataclass(frozen=True, kw_only=True)
class ReheatOperation:
    """[[process.operation]] kind = "reheat": back into the furnace."""

    name: str = key("", doc="the operation's name ('' = its kind)")
    furnace_temperature_K: float | None = key(
        low=1.0, high=5000.0, doc="furnace temperature (K), with time_s"
    )
    time_s: float | None = key(low=0.0, low_open=True, high=1e5, doc="time in the furnace (s)")
    dt_s: float | None = key(
        low=0.0, low_open=True, doc="largest time step in the furnace (s; default time.dt_s)"
    )
    htc_W_m2K: float = key(
        50.0, low=0.0, high=1e7, doc="convection coefficient in the furnace (W/m^2 K)"
    )
    emissivity: float | None = key(
        low=0.0, high=1.0, doc="emissivity in the furnace (default thermal.emissivity)"
    )
    set_temperature_K: float | None = key(
        low=1.0,
        high=5000.0,
        doc="instead of a furnace and a time: the whole part is set to this temperature (K)",
    )


OPERATION_CLASSES = {
    "forming": FormingOperation,
    "dwell": DwellOperation,
    "trim": TrimOperation,
    "reheat": ReheatOperation,
}


OPERATION_SCHEMA = {kind: schema_of(cls) for kind, cls in OPERATION_CLASSES.items()}


@dataclass(frozen=True)
class Operation:
    """One validated operation: its kind, name, keys (the kind's class) and the typed
    config of its scene (forming: the base config with the operation's sections over it;
    the others: the config of the forming operation before them, or of the first)."""

    index: int  # 1-based position in the process
    kind: str
    name: str
    keys: Any
    config: Config

    @property
    def forming(self) -> bool:
        """Whether the operation is a blow between dies."""
        return self.kind == "forming"

    @property
    def label(self) -> str:
        return f"process.operation[{self.index}] ({self.name})"


def _where(i: int, name: str) -> str:
    return f"process.operation[{i}] ({name})"


def _merged(base: dict, table: dict, where: str) -> dict:
    """The base document with the operation's section tables over it, key by key."""
    doc = copy.deepcopy(base)
    for sec in OPERATION_SECTIONS:
        if sec not in table:
            continue
        given = table[sec]
        if not isinstance(given, dict):
            raise ConfigError(f"{where}: {sec} must be a table of [{sec}] keys")
        if sec == "thermal":
            for k in PROCESS_THERMAL_KEYS:
                if k in given:
                    raise ConfigError(
                        f"{where}: thermal.{k} belongs to the whole process (set it in [thermal])"
                    )
        doc.setdefault(sec, {}).update(copy.deepcopy(given))
    return doc


def _operation_keys(kind: str, table: dict, where: str) -> dict:
    """The operation's own keys (not its section tables), checked and defaulted."""
    schema = OPERATION_SCHEMA[kind]
    sections = OPERATION_SECTIONS if kind == "forming" else ()
    out = {}
    for k in table:
        if k != "kind" and k not in schema and k not in sections:
            allowed = ", ".join(["kind", *schema, *sections])
            raise ConfigError(
                f"{where}: unknown key {k!r} of a {kind} operation; allowed: {allowed}"
            )
    for k, f in schema.items():
        if k in table:
            out[k] = check_value(f"{where}: {k}", f, table[k])
        elif f.default is None:
            out[k] = None
        else:
            out[k] = copy.deepcopy(f.default)
    return out


def _check_operation(kind: str, keys: dict, table: dict, where: str, thermal: bool) -> None:
    """What each kind needs beyond its keys' ranges."""
    if kind == "forming":
        if "die" not in table:
            raise ConfigError(f"{where}: a forming operation needs its own dies: a die table")
        given = [k for k in ("travel_mm", "final_gap_mm") if keys[k] is not None]
        if "reduction" in table["die"]:
            given.append("die.reduction")
        if len(given) != 1:
            raise ConfigError(
                f"{where}: give exactly one stroke: die.reduction, travel_mm or final_gap_mm "
                f"(given: {', '.join(given) or 'none'})"
            )
    elif kind == "dwell":
        if keys["time_s"] is None:
            raise ConfigError(f"{where}: missing required key time_s (the time in air, s)")
    elif kind == "trim":
        if keys["radius_mm"] is None:
            raise ConfigError(f"{where}: missing required key radius_mm (the trim radius, mm)")
    elif kind == "reheat":
        furnace = keys["furnace_temperature_K"] is not None or keys["time_s"] is not None
        if furnace == (keys["set_temperature_K"] is not None):
            raise ConfigError(
                f"{where}: give furnace_temperature_K and time_s, or set_temperature_K"
            )
        if furnace and (keys["furnace_temperature_K"] is None or keys["time_s"] is None):
            missing = "time_s" if keys["time_s"] is None else "furnace_temperature_K"
            raise ConfigError(f"{where}: missing required key {missing} of the furnace")
        if not thermal:
            raise ConfigError(f'{where}: a reheat needs thermal.model = "coupled"')


def _forming_document(base: dict, table: dict, keys: dict, where: str) -> dict:
    """The validated scene document of a forming operation."""
    doc = _merged(base, table, where)
    if "reduction" not in table["die"]:
        # the stroke comes from travel_mm / final_gap_mm once the incoming part is known
        # (jaxform.process); a placeholder reduction lets the sections validate
        doc["die"]["reduction"] = 0.5
    try:
        out = load_config(doc)
    except ConfigError as err:
        raise ConfigError(f"{where}: {err}") from None
    if out["press"]["model"] != "speed":
        raise ConfigError(
            f"{where}: press.model = {out['press']['model']!r}: the operations of a process "
            'run on the hydraulic press (press.model = "speed") so far'
        )
    if out["die"]["path_time_s"]:
        raise ConfigError(
            f"{where}: die.path_time_s: the dies of a process move at die.speed_mm_s so far"
        )
    if out["thermal"]["dwell_s"] > 0.0:
        raise ConfigError(f"{where}: thermal.dwell_s: in a process a dwell is an operation")
    return out


def _table_list(raw_process: Any) -> list:
    if not isinstance(raw_process, dict) or set(raw_process) != {"operation"}:
        raise ConfigError(
            "process: must hold only the array of tables [[process.operation]] (kind = "
            f"{', '.join(repr(k) for k in KINDS)})"
        )
    ops = raw_process["operation"]
    if not isinstance(ops, list) or not ops or not all(isinstance(t, dict) for t in ops):
        raise ConfigError("process.operation: must be a non-empty array of tables")
    return ops


def process_document(doc: dict) -> dict:
    """The TOML document of a validated process config: the base sections and the
    ``[[process.operation]]`` tables (each forming operation's sections as far as they
    differ from the base's; unset keys left out)."""
    base = {k: v for k, v in doc.items() if k != "process"}
    tables = []
    for op in doc["process"]:
        table = {"kind": op["kind"]}
        table.update({k: v for k, v in op["keys"].items() if v is not None and v != ""})
        if op["kind"] == "forming":
            for sec in OPERATION_SECTIONS:
                own = op["document"].get(sec) or {}
                diff = {k: v for k, v in own.items()
                        if v is not None and base.get(sec, {}).get(k) != v}  # fmt: skip
                if sec == "die" and op["stroke_by"] != "reduction":
                    diff.pop("reduction", None)
                elif sec == "die":  # the operation's own stroke, even where the base has it
                    diff["reduction"] = own["reduction"]
                if diff or sec == "die":
                    table[sec] = diff
        tables.append(table)
    return {**base, "process": {"operation": tables}}


def load_document(path_or_dict: str | PathLike | dict, overrides=()) -> dict:
    """The validated document of a config with or without ``[[process.operation]]``
    (:func:`jaxform.config.load_config`; with a process, a ``process`` entry: one dict per
    operation with ``kind``, ``name``, ``keys`` and, for forming, ``document``).
    ``--set`` overrides apply to the base sections.  Raises ConfigError (one line)."""
    raw = copy.deepcopy(path_or_dict) if isinstance(path_or_dict, dict) else read_toml(path_or_dict)
    if "process" not in raw:
        return load_config(raw, overrides)
    if isinstance(raw["process"], list):  # a document this function gave: validated anew
        raw = process_document(raw)
    tables = _table_list(raw.pop("process"))
    for text in overrides:
        section, k, value = parse_override(text)
        if section == "process":
            raise ConfigError(f"--set {text}: a process's operations are set in the config file")
        sec = raw.setdefault(section, {})
        if isinstance(sec, dict):
            sec[k] = value
    base = load_config(raw)
    thermal = base["thermal"]["model"] == "coupled"
    ops = [_operation(i, table, raw, thermal) for i, table in enumerate(tables, start=1)]
    if not any(op["kind"] == "forming" for op in ops):
        raise ConfigError("process.operation: a process needs at least one forming operation")
    if base["mesh"]["rezone_quality"] > 0.0 and len(ops) > 1:
        raise ConfigError(
            "mesh.rezone_quality > 0: a process carries the part on its deformed mesh; "
            "use [remesh] triggers instead of rezoning"
        )
    base["process"] = ops
    return base


def _operation(i: int, table: dict, raw: dict, thermal: bool) -> dict:
    """The validated ``i``-th operation table (1-based) of a process over the base
    document ``raw`` (``thermal``: the base is coupled): kind, name, keys and, for a
    forming operation, its merged document and what sets its stroke."""
    kind = table.get("kind")
    if kind not in KINDS:
        where = _where(i, str(table.get("name", "?")))
        raise ConfigError(f"{where}: kind = {kind!r}: must be one of {', '.join(map(repr, KINDS))}")
    name = str(table.get("name") or kind)
    where = _where(i, name)
    keys = _operation_keys(kind, table, where)
    keys["name"] = name
    _check_operation(kind, keys, table, where, thermal)
    op = {"kind": kind, "name": name, "keys": keys}
    if kind == "forming":
        op["document"] = _forming_document(raw, table, keys, where)
        op["stroke_by"] = "reduction" if "reduction" in table["die"] else (
            "travel_mm" if keys["travel_mm"] is not None else "final_gap_mm")  # fmt: skip
    return op


def operations(doc: dict) -> tuple[Operation, ...]:
    """The typed operations of a document from :func:`load_document` (with a process);
    a dwell, trim or reheat takes the config of the forming operation before it (the
    first forming operation's for those in front of it)."""
    ops = doc["process"]
    first = next(op["document"] for op in ops if op["kind"] == "forming")
    current, out = first, []
    for i, op in enumerate(ops, start=1):
        if op["kind"] == "forming":
            current = op["document"]
        cls = OPERATION_CLASSES[op["kind"]]
        keys = cls(**op["keys"])
        out.append(Operation(i, op["kind"], op["name"], keys, typed(current)))
    return tuple(out)


@dataclass(frozen=True, eq=False)
class Process:
    """A validated multi-stage config: its document (:func:`load_document`, with the
    ``process`` entry; written back as the run's config.toml) and its typed operations."""

    document: dict
    operations: tuple[Operation, ...]


def load_typed(path_or_dict: str | PathLike | dict, overrides=()) -> Config | Process:
    """What a command runs, validated once: the typed :class:`Config` of a scene, or the
    :class:`Process` of a config with ``[[process.operation]]`` tables (``--set``
    overrides apply to the base sections).  Raises ConfigError (one line)."""
    doc = load_document(path_or_dict, list(overrides))
    if "process" in doc:
        return Process(doc, operations(doc))
    return typed(doc)


def describe_process_schema() -> str:
    """Markdown tables of the operation keys (the config reference)."""
    lines = [
        "## [[process.operation]]",
        "",
        "A multi-stage process (docs: Multi-stage processes): an array of tables, each with "
        f"`kind` = {', '.join(f'`{k}`' for k in KINDS)}. A forming operation also takes the "
        f"tables {', '.join(f'`{s}`' for s in OPERATION_SECTIONS)} (the sections' keys, over "
        "the base config's).",
        "",
    ]
    for kind, schema in OPERATION_SCHEMA.items():
        lines += [f"### kind = \"{kind}\"", "", "| key | type | default | allowed | description |",
                  "|---|---|---|---|---|"]  # fmt: skip
        for k, f in schema.items():
            default = "optional" if f.default is None else f"`{f.default!r}`"
            lines.append(f"| `{k}` | {f.kind} | {default} | {f.allowed()} | {f.doc} |")
        lines.append("")
    return "\n".join(lines)


def check_process_design(process: Process, groups=None, where: str = "design.variables") -> None:
    """Refuse, before anything compiles, a process's gradient run (jaxform design,
    taylor-test) whose [design] the process cannot serve: design.operation or
    design.objective_operation naming no operation; a group (``groups``, default
    design.variables; ``<operation>.<group>`` or ``<group>``) that is unknown, names no
    operation, or that its operation cannot vary (a dwell's die, a forming operation's
    dwell time, the group's requirements on the operation's config); an objective that is
    not a process's or whose operation lacks what it reads.  One line naming the key."""
    ops = process.operations
    d = ops[0].config.design
    names = [op.name for op in ops]
    by_name = {op.name: op for op in ops}
    for g in d.operation_variables:
        if "." not in g:
            raise ConfigError(
                f"design.operation_variables = {list(d.operation_variables)!r}: {g!r} names "
                "no operation: each entry is '<operation>.<group>'"
            )
    for k in ("operation", "objective_operation"):
        value = getattr(d, k)
        if value and value not in by_name:
            raise ConfigError(
                f"design.{k} = {value!r}: no operation of that name; the process has: "
                f"{', '.join(names)}"
            )
    if groups is None:
        groups = [*d.variables, *d.operation_variables]
    listed = " ".join(groups)
    shown = f"{where} = {groups!r}" if where.startswith("design.") else f"{where} {listed}"
    if not groups:
        raise ConfigError(f"{shown}: name at least one design group")
    first_forming = next(op for op in ops if op.forming)
    for g in groups:
        _check_process_group(g, by_name, by_name.get(d.operation, first_forming), shown)
    if d.robust:
        _check_robust(d, [op for op in ops if op.forming])
    target = by_name[d.objective_operation] if d.objective_operation else None
    target = target or [op for op in ops if op.forming][-1]
    if d.objective == requirements.PROCESS_WEIGHTED_SUM:
        _check_process_terms(d, by_name, target)
        return
    if d.objective not in requirements.PROCESS_OBJECTIVES:
        raise ConfigError(
            f"design.objective = {d.objective!r}: a process's objective is one of "
            f"{', '.join(requirements.PROCESS_OBJECTIVES)}, weighted_sum (of "
            "design.objective_operation)"
        )
    _check_process_objective(d.objective, target, f"design.objective = {d.objective!r}")


def _check_robust(d, forming: list[Operation]) -> None:
    """A robust design needs scenarios, coupled heat for die temperatures and a friction
    coefficient to set for friction factors."""
    where = f"design.robust = {d.robust!r}"
    if not d.robust_friction and not d.robust_die_temperature_K:
        raise ConfigError(
            f"{where}: give the scenarios, design.robust_friction and/or "
            "design.robust_die_temperature_K"
        )
    if d.robust_die_temperature_K:
        cold = [op for op in forming if op.config.thermal.model != "coupled"]
        if cold:
            raise ConfigError(
                f"design.robust_die_temperature_K: {cold[0].label} has no coupled heat "
                '(thermal.model = "coupled")'
            )
    for values, kind in ((d.robust_friction, "friction"),
                         (d.robust_die_temperature_K, "thermal")):  # fmt: skip
        both = [g for g in (*d.variables, *d.operation_variables)
                if values and g.rpartition(".")[2] == kind]  # fmt: skip
        if both:
            raise ConfigError(
                f"design.robust: {both[0]!r} would be both designed and uncertain (its "
                f"scenarios set it): drop it from the design or from the scenarios"
            )
    if d.robust_friction and not any(
        FRICTION_COEFFICIENT.get(op.config.friction_of(die).model)
        for op in forming
        for die in op.config.die_sections()
    ):
        raise ConfigError(
            "design.robust_friction: no die of a forming operation has a friction "
            "coefficient (friction.model = 'coulomb' or 'shear')"
        )


def _check_process_objective(name: str, target: Operation, what: str) -> None:
    """Refuse the process objective ``name`` of the operation ``target`` where the
    operation lacks what it reads (``what``: the key that asked, for the line)."""
    needs = list(requirements.OBJECTIVES[name].requires)
    if name == "die_fill":  # the part inside the flash land
        needs.append(requirements.part_radius)
    reasons = [r for need in needs if (r := need(target.config)) is not None]
    if name in ("flash_volume", "die_fill") and not target.forming:
        reasons.insert(0, "a forming operation")
    if reasons:
        raise ConfigError(f"{what} of {target.label} needs {reasons[0]}")


def _check_process_terms(d, by_name: dict, target: Operation) -> None:
    """A process's weighted sum: design.terms (of ``target``) and design.operation_terms
    ('<operation>.<objective>'), as many design.term_weights, each >= 0."""
    terms = [*d.terms, *d.operation_terms]
    if not terms or len(terms) != len(d.term_weights):
        raise ConfigError(
            f"design.objective = 'weighted_sum' of a process needs design.terms (now "
            f"{list(d.terms)}) and design.operation_terms (now {list(d.operation_terms)}) "
            f"with as many design.term_weights (now {list(d.term_weights)})"
        )
    if any(w < 0.0 for w in d.term_weights):
        raise ConfigError(f"design.term_weights = {list(d.term_weights)}: must be >= 0")
    shown = f"design.operation_terms = {list(d.operation_terms)!r}"
    for spec in terms:
        op_name, _, name = spec.rpartition(".")
        own = spec in d.operation_terms
        if own and not op_name:
            raise ConfigError(f"{shown}: {spec!r} names no operation: each entry is "
                              "'<operation>.<objective>'")  # fmt: skip
        if own and op_name not in by_name:
            raise ConfigError(f"{shown}: {spec!r}: no operation named {op_name!r}; the "
                              f"process has: {', '.join(by_name)}")  # fmt: skip
        if name not in requirements.PROCESS_OBJECTIVES:
            where = shown if own else f"design.terms = {list(d.terms)!r}"
            raise ConfigError(f"{where}: {spec!r}: a process's term is one of "
                              f"{', '.join(requirements.PROCESS_OBJECTIVES)}")  # fmt: skip
        op = by_name[op_name] if own else target
        _check_process_objective(name, op, f"design term {spec!r}")


def _check_process_group(spec: str, by_name: dict, default: Operation, shown: str) -> None:
    op_name, _, kind = spec.rpartition(".")
    if not op_name and kind in requirements.PROCESS_GROUPS:
        if kind not in ("billet", "billet_volume"):
            requirements.check_groups(default.config, (kind,), shown)
        return
    if kind not in requirements.OPERATION_GROUPS:
        allowed = [*requirements.PROCESS_GROUPS]
        allowed += [f"<operation>.{g}" for g in requirements.OPERATION_GROUPS]
        raise ConfigError(f"{shown}: {spec!r} is not a process's design group; allowed: "
                          f"{', '.join(allowed)}")  # fmt: skip
    if op_name and op_name not in by_name:
        raise ConfigError(
            f"{shown}: {spec!r}: no operation named {op_name!r}; the process has: "
            f"{', '.join(by_name)}"
        )
    op = by_name[op_name] if op_name else default
    air = getattr(op.keys, "time_s", None) is not None and op.config.thermal.model == "coupled"
    if kind == "dwell":
        if not air:
            raise ConfigError(
                f"{shown}: {spec!r}: {op.label} is no dwell or furnace with time_s and "
                'thermal.model = "coupled"'
            )
        return
    if kind == "thermal" and (op.forming or air):
        requirements.check_groups(op.config, (kind,), shown)
        return
    if not op.forming:
        raise ConfigError(f"{shown}: {spec!r}: {op.label} is no forming operation")
    requirements.check_groups(op.config, (kind,), shown)
