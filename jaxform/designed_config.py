"""The config of a design: the TOML document whose forward run (`jaxform run`) is the run
at that design, written by `jaxform design` as designed.toml beside the configured
config.toml.  It runs with the design's solver (full Newton, no probe of the first step;
:func:`_as_the_design_ran`), which is what makes the two one run.

    (problem, design, the loaded Config or Process) --designed_document--> Designed
        (TOML document, material table, first mesh) --write_designed--> designed.toml

Each design group writes the keys that set what it varies, in the order the problem
applies them:

- die, die_spline (and billet, billet_volume, which lift the first die): the top die's
  ``profile_mm``, its points at the design as a polyline (a mirrored bottom die then
  written as its own points);
- billet, billet_volume: ``billet.diameter_mm``, ``billet.height_mm`` (and the first
  operation's ``die.reduction`` so that its die travels as far as the design's);
- friction: each die's coefficient (``[friction]``, or ``[<die>.friction]`` where the
  dies' coefficients are designed apart);
- speed: ``die.speed_mm_s`` (or ``die.path_time_s``) and ``time.dt_s`` scaled alike (the
  same steps);
- thermal: the ``[thermal]`` keys (a dwell's: its own air keys);
- dwell: the dwell's ``time_s`` and ``dt_s`` scaled alike;
- material: a material file (designed_material.toml: the preset's with the designed
  ``[params]``) named by ``material.preset``;
- preform, nodes: the first mesh at the design as a mesh file (designed_mesh.msh) named
  by ``mesh.file``.
"""

from __future__ import annotations

import copy
import csv
from dataclasses import dataclass, replace
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import tomli_w

from jaxform.config import Config, toml_form
from jaxform.design import parametrize as par
from jaxform.material_files import read_material_file
from jaxform.mesh import Mesh, write_mesh
from jaxform.process_config import Process, process_document

MATERIAL_FILE = "designed_material.toml"
MESH_FILE = "designed_mesh.msh"
# the groups that set the top die's points (written as the points at the design)
_DIE_GROUPS = (par.DieProfile, par.DieSpline, par.BilletAspect, par.BilletVolume)
# the groups that move the first mesh's nodes (written as a mesh file)
_NODE_GROUPS = (par.PreformCosine, par.NodalCoordinates)


class NoConfigForm(ValueError):
    """A design group that no config key can express (a reheat's thermal group)."""


@dataclass
class _Target:
    """Where one scene's (or operation's) keys go: ``table`` (the TOML form of the scene,
    or the operation's table of a process), its configured ``config`` and its inputs at
    the design (``inputs``: the top die's points are read there)."""

    table: dict
    config: Config
    inputs: object

    def section(self, name: str) -> dict:
        return self.table.setdefault(name, {})


@dataclass(frozen=True)
class Designed:
    """A design as files: the config's TOML ``document``, the material file's table
    (``material``, where a material group is designed) and the first mesh (``mesh``, where
    a preform or nodes group moves its nodes; written as a mesh file, ``mesh.file``)."""

    document: dict
    material: dict | None = None
    mesh: Mesh | None = None


def designed_document(loaded: Config | Process, problem, design) -> Designed:
    """The config of ``loaded`` at ``design`` of ``problem`` (a single scene's
    :class:`jaxform.design.problem.DesignProblem` or a process's design problem)."""
    design = {k: np.asarray(v) for k, v in design.items()}
    if isinstance(loaded, Process):
        doc, material = _process_document(loaded, problem, design)
    else:
        doc = toml_form(loaded.to_dict())
        target = _Target(doc, loaded, _stage_inputs(problem, design)[0])
        material = None
        for g in problem.groups:
            material = _write(g, design[g.name], target, material) or material
    _as_the_design_ran(doc)
    mesh = None
    first = getattr(problem, "first", problem)
    if any(isinstance(getattr(g, "inner", g), _NODE_GROUPS) for g in first.groups):
        scene = first.plan.stages[0].scene if hasattr(first, "on_stage") else first.scene
        coords = np.asarray(_stage_inputs(problem, design)[0].coords)
        mesh = replace(scene.mesh, coords=coords)
    return Designed(doc, material, mesh)


def _as_the_design_ran(doc: dict) -> None:
    """Set ``doc``'s solver to the one the design's forward runs use
    (:meth:`jaxform.scenes.Scene.full_newton`): ``solver.newton = "newton"`` and
    ``time.first_step_probe = 0`` (in every operation's own ``[time]`` too).  Modified
    Newton and a probed first step converge each step to the same tolerance but by other
    iterates, so the adaptive steps, and with them the remeshes, fall elsewhere; at a
    design on the edge of filling that moved the fill by 0.03 %."""
    doc.setdefault("solver", {})["newton"] = "newton"
    doc.setdefault("time", {})["first_step_probe"] = 0.0
    for table in doc.get("process", {}).get("operation", []):
        if "first_step_probe" in table.get("time", {}):
            table["time"]["first_step_probe"] = 0.0


def _stage_inputs(problem, design) -> dict:
    """{stage index: its inputs at ``design``} of a process's design problem (each stage
    that has a scene), or {0: the inputs} of a single scene's."""
    first = getattr(problem, "first", problem)  # a Replanning problem's groups act there
    # groups the design leaves alone (a robust design's uncertain ones): as configured
    traced = {n: jnp.asarray(v) for n, v in {**first.start, **design}.items()}
    if not hasattr(first, "on_stage"):
        return {0: first.run_inputs(traced)[0]}
    one = jnp.ones(1)
    return {k: first.on_stage(traced, k, stage.scene.inputs, one)[0]
            for k, stage in enumerate(first.plan.stages)}  # fmt: skip


def _process_document(process: Process, problem, design) -> tuple[dict, dict | None]:
    first = getattr(problem, "first", problem)
    doc = toml_form(process_document(process.document))
    tables = doc["process"]["operation"]
    stage_of_op = {s.name: k for k, s in enumerate(first.plan.stages)}
    inputs = _stage_inputs(problem, design)
    targets = {}
    for op, table in zip(process.operations, tables):
        k = stage_of_op.get(op.name)
        if k is not None:
            targets[k] = _Target(table, op.config, inputs[k])
    base = _Target(doc, process.operations[0].config, None)
    material = None
    for g in first._ordered():
        if g.name not in design:  # a robust design's uncertain group: as configured
            continue
        if g.prefix:  # an operation's group
            material = _write(g.inner, design[g.name], targets[g.stages[0]], material) or material
            continue
        if isinstance(g.inner, par.BilletAspect | par.BilletVolume):  # the first die follows
            first_op = targets[g.stages[0]]
            _write_die(first_op)
            die = first_op.table.get("die", {})
            if "reduction" in die:  # the same travel (the group keeps the stroke)
                die["reduction"] = float(die["reduction"]) / _height_factor(g.inner, design[g.name])
        if isinstance(g.inner, par.Thermal):  # every operation: the base keys, none over them
            for t in targets.values():
                for n in g.inner.names:
                    t.table.get("thermal", {}).pop(n, None)
        material = _write(g.inner, design[g.name], base, material) or material
    return doc, material


def _write(group, u: np.ndarray, target: _Target, material: dict | None) -> dict | None:
    """Write ``group``'s keys at ``u`` into ``target``; the material file's table where the
    group is the material's, else None."""
    if isinstance(group, _DIE_GROUPS):
        if target.inputs is not None:
            _write_die(target)
        if isinstance(group, par.BilletAspect | par.BilletVolume):
            _write_billet(group, u, target)
        return None
    if isinstance(group, par.Friction):
        for v, value in zip(group.variables, u):
            section = v.key.rsplit(".", 1)[0]  # friction, die.friction, bottom_die.friction
            die = {"top": "die", "bottom": "bottom_die", "side": "side_die"}[v.die_name]
            if section == "friction" and len(group.variables) > 1:
                section = f"{die}.friction"  # the dies' coefficients may differ now
            table = target.section(section.split(".")[0])
            if "." in section:
                table = table.setdefault("friction", {})
            table[v.field] = float(value)
        return None
    if isinstance(group, par.RamSpeed):
        slow = float(np.exp(-u[0]))
        die = target.section("die")
        if target.config.die.path_time_s:
            die["path_time_s"] = [float(t) * slow for t in target.config.die.path_time_s]
        else:
            die["speed_mm_s"] = group.physical(u)["speed_mm_s"]
        target.section("time")["dt_s"] = float(target.config.time.dt_s) * slow
        return None
    if isinstance(group, par.DwellTime):
        longer = float(np.exp(u[0]))
        target.table["time_s"] = group.physical(u)["dwell_time_s"]
        dt = target.table.get("dt_s") or target.config.time.dt_s
        target.table["dt_s"] = float(dt) * longer
        return None
    if isinstance(group, par.Thermal):
        values = {n: float(v) for n, v in group.values(jnp.asarray(u)).items()}
        if target.table.get("kind") == "dwell":  # a dwell's own air keys
            target.table.update(values)
        elif target.table.get("kind") is not None and target.table["kind"] != "forming":
            raise NoConfigForm(f"design group 'thermal' of a {target.table['kind']}: no keys")
        else:
            target.section("thermal").update(values)
        return None
    if isinstance(group, _NODE_GROUPS):  # the first mesh's nodes: the mesh file
        return None
    if isinstance(group, par.MaterialParams):
        table, _ = read_material_file(target.config.material.preset, "material.preset")
        table = copy.deepcopy(table)
        table.setdefault("params", {}).update(group.physical(u))
        return table
    raise NoConfigForm(f"design group {group.name!r}: no config keys")


def _write_die(target: _Target) -> None:
    """The top die's points at the design as its polyline ``die.profile_mm`` (a mirrored
    bottom die keeps its configured points, written as its own)."""
    members = target.inputs.die.members
    die = target.section("die")
    die["profile_mm"] = np.asarray(members[0].points).tolist()
    die["profile_kind"] = "polyline"
    bottom = target.config.bottom_die
    if bottom is not None and bottom.mirror and len(members) > 1:
        table = target.section("bottom_die")
        table["mirror"] = False
        table["profile_mm"] = np.asarray(members[1].points)[::-1].tolist()
        table["profile_kind"] = "polyline"


def _write_billet(group, u: np.ndarray, target: _Target) -> None:
    b = target.config.billet
    if b is None:
        raise NoConfigForm(f"design group {group.name!r}: the workpiece is no [billet]")
    tall = _height_factor(group, u)
    phys = group.physical(u)
    wide = phys["billet_diameter_factor"] if isinstance(group, par.BilletAspect) else tall
    section = target.section("billet")
    section["diameter_mm"] = float(section.get("diameter_mm", b.diameter_mm)) * wide
    section["height_mm"] = float(section.get("height_mm", b.height_mm)) * tall


def _height_factor(group, u: np.ndarray) -> float:
    """How much taller the billet group makes the billet at ``u``."""
    phys = group.physical(u)
    if isinstance(group, par.BilletAspect):
        return phys["billet_height_factor"]
    return phys["billet_volume_factor"] ** (1.0 / (3.0 if group.axisymmetric else 2.0))


def write_designed(loaded: Config | Process, problem, design, out_dir,
                   announce=None) -> Path | None:  # fmt: skip
    """Write designed.toml (and designed_material.toml where the material is designed) to
    ``out_dir`` and say so to ``announce``; its path, or None (and the reason to
    ``announce``) where a group has no config form (:class:`NoConfigForm`)."""
    out = Path(out_dir)
    try:
        designed = designed_document(loaded, problem, design)
    except NoConfigForm as err:
        if announce is not None:
            announce(f"  {err}: no designed.toml")
        return None
    doc = designed.document
    if designed.material is not None:
        path = (out / MATERIAL_FILE).resolve()
        path.write_bytes(tomli_w.dumps(designed.material).encode())
        doc.setdefault("material", {})["preset"] = str(path)
    if designed.mesh is not None:
        path = (out / MESH_FILE).resolve()
        write_mesh(path, designed.mesh)
        doc.setdefault("mesh", {})["file"] = str(path)
    target = out / "designed.toml"
    target.write_bytes(tomli_w.dumps(doc).encode())
    refused = _refusal(target)
    if announce is not None and refused:
        announce(f"  the best design's config: {target}, which a run refuses: {refused}")
    elif announce is not None:
        announce(f"  the best design's config: {target} (jaxform run runs the design)")
    return target


def _refusal(path: Path) -> str:
    """Why `jaxform run` would refuse the config at ``path`` before its first step ('' if
    it would not): its keys, and the first operation's (or the scene's) set-up, where a
    die that the design moved into the part at the start is refused."""
    from jaxform.errors import ConfigError
    from jaxform.process import check_process, forming_scene, prepare
    from jaxform.process_config import load_typed
    from jaxform.scenes import build_scene

    try:
        loaded = load_typed(path)
        if isinstance(loaded, Process):
            ops = loaded.operations
            initial = prepare(ops)
            check_process(ops, initial)
            forming_scene(ops[0], initial, initial)
        else:
            build_scene(loaded)
    except ConfigError as err:
        return str(err)
    return ""


def die_profiles(problem, start, best) -> list[dict]:
    """The top die of each operation whose die a group moves (die, die_spline, billet,
    billet_volume), at ``start`` and at ``best``: rows of operation, point, r_mm,
    z_start_mm, z_designed_mm (the groups move heights only).  [] where none does."""
    first = getattr(problem, "first", problem)
    moved = sorted({k for g in first.groups if isinstance(getattr(g, "inner", g), _DIE_GROUPS)
                    for k in getattr(g, "stages", (0,))})  # fmt: skip
    if not moved:
        return []
    before, after = _stage_inputs(problem, start), _stage_inputs(problem, best)
    stages = getattr(getattr(first, "plan", None), "stages", None)
    rows = []
    for k in moved:
        name = stages[k].name if hasattr(first, "on_stage") else "scene"
        p0 = np.asarray(before[k].die.members[0].points)
        p1 = np.asarray(after[k].die.members[0].points)
        rows += [dict(operation=name, point=i, r_mm=float(p0[i, 0]), z_start_mm=float(p0[i, 1]),
                      z_designed_mm=float(p1[i, 1])) for i in range(len(p0))]  # fmt: skip
    return rows


def write_design_files(loaded: Config | Process, problem, hist, out_dir, announce=None) -> None:
    """What a design writes beside its history: designed.toml (:func:`write_designed`) at
    the best design and, where a group moves a die, die_profiles.csv and die_profiles.png
    (each such die at the start and the best design)."""
    from jaxform.plot import die_profiles as plot_profiles

    best = hist.designs[hist.best]
    write_designed(loaded, problem, best, out_dir, announce)
    rows = die_profiles(problem, hist.designs[0], best)
    if rows:
        out = Path(out_dir)
        with open(out / "die_profiles.csv", "w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
        plot_profiles(rows, out / "die_profiles.png")
