"""The code's layout keeps its promises: workpieces own their knowledge, the typed config
round-trips, layers import one way, no function takes more than 8 parameters, and the
caller-owned loop (init/step) takes the same steps as the host loop."""

import ast
import dataclasses
import io
import subprocess
from pathlib import Path

import numpy as np
import pytest

from jaxform.cli import Progress
from jaxform.config import SECTIONS, Config, load_config, typed
from jaxform.process_config import load_document
from jaxform.scenes import build_scene
from jaxform.simulation import SimulationError, init, simulate, step
from jaxform.workpieces import Billet, Block, Membrane, MeshFile, Ring, workpiece_of

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = sorted((ROOT / "configs").glob("*.toml"))
PACKAGE = ROOT / "jaxform"


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: p.stem)
def test_typed_config_round_trips_and_is_frozen(path):
    """Reference: the validated document itself; the typed Config gives it back exactly
    (a process's base sections)."""
    doc = load_document(path)
    doc.pop("process", None)
    cfg = typed(doc)
    assert cfg.to_dict() == doc
    assert set(SECTIONS) >= set(doc)
    hash(cfg)  # frozen and hashable: lists became tuples
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.mesh.nr = 3


@pytest.mark.parametrize(
    "name, cls, sets, height, half",
    [
        ("upsetting_seed", Billet, ("top", "side"), 7.5, True),
        ("ring_compression", Ring, ("top", "outer", "inner"), None, True),
        ("prandtl_punch", Block, ("top",), None, False),
        ("cooks_membrane", Membrane, (), None, False),
    ],
)
def test_workpiece_classes_own_their_sets_and_stroke(name, cls, sets, height, half):
    """Reference: the workpiece sections of the shipped configs (module docstring of
    jaxform.workpieces): contact sets, the height the reduction refers to, the stroke."""
    cfg = typed(load_config(ROOT / "configs" / f"{name}.toml"))
    piece = workpiece_of(cfg)
    assert isinstance(piece, cls)
    mesh = piece.build_mesh()
    assert piece.contact_sets(mesh) == sets
    assert piece.half_height is half and piece.pressed is (cls is not Membrane)
    section = getattr(cfg, piece.name)
    expected = getattr(section, "height_mm", getattr(section, "depth_mm", None))
    if cls is not Membrane:
        assert piece.reference_height_mm == (height or expected)
    assert ("preform" in piece.design_groups()) is (cls is Billet)


def test_mesh_file_workpiece_keeps_its_base(tmp_path):
    """A mesh file replaces the billet's section: its sets come from the file, the
    reduction still refers to the billet's height, and preforms (which need the
    structured mesh) are not offered."""
    from jaxform.mesh import write_mesh

    cfg = typed(load_config(ROOT / "configs" / "upsetting_seed.toml", ["mesh.nr=2", "mesh.nz=2"]))
    path = tmp_path / "billet.msh"
    write_mesh(path, workpiece_of(cfg).build_mesh())
    piece = workpiece_of(typed(load_config(ROOT / "configs" / "upsetting_seed.toml",
                                           [f"mesh.file={path}"])))  # fmt: skip
    assert isinstance(piece, MeshFile) and piece.grid is None
    assert piece.reference_height_mm == 7.5
    assert "preform" not in piece.design_groups()
    assert piece.contact_sets(piece.build_mesh()) == ("top", "side")


def test_ring_history_reads_the_mid_plane_nodes():
    """Reference: a ring moved rigidly outward by 0.1 mm at every node: both diameters
    grow by 0.2 mm, read at the nodes on the symmetry plane."""
    cfg = typed(load_config(ROOT / "configs" / "ring_compression.toml"))
    piece = workpiece_of(cfg)
    mesh = piece.build_mesh()
    pos = mesh.coords[None] + np.array([0.1, 0.0])
    cols = piece.extra_history(mesh, pos, pos - mesh.coords)
    assert cols["inner_diameter_mm"][0] == pytest.approx(cfg.ring.inner_diameter_mm + 0.2)
    assert cols["outer_diameter_mm"][0] == pytest.approx(cfg.ring.outer_diameter_mm + 0.2)


def _imports(path: Path) -> set[str]:
    """The jaxform modules (and names) ``path`` imports at run time (not the imports
    under ``if TYPE_CHECKING:``, which only name types for the reader)."""
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and getattr(node.test, "id", "") == "TYPE_CHECKING":
            node.body = []
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.add(node.module)
            out.update(f"{node.module}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
    return {m for m in out if m.startswith("jaxform")}


@pytest.mark.parametrize(
    "modules, forbidden",
    [
        (["design/*.py"], ("jaxform.config", "jaxform.io", "jaxform.plot", "jaxform.driver")),
        (
            ["stepping.py", "solver.py", "assembly.py", "formulations.py", "contact.py"],
            (
                "jaxform.postprocess",
                "jaxform.laps",
                "jaxform.io",
                "jaxform.plot",
                "jaxform.simulation",
                "jaxform.driver",
                "jaxform.config",
                "jaxform.scenes",
            ),
        ),  # fmt: skip
        (["solver.py"], ("jaxform.element", "jaxform.formulations")),
        (["workpieces.py", "scenes.py"], ("jaxform.io", "jaxform.plot", "jaxform.driver")),
        (["study/*.py"], ("jaxform.cli",)),
        (
            ["config/*.py", "design/requirements.py"],
            (
                "jaxform.scenes",
                "jaxform.workpieces",
                "jaxform.simulation",
                "jaxform.process",
                "jaxform.driver",
                "jaxform.cli",
                "jaxform.design.problem",
                "jaxform.design.parametrize",
                "jaxform.design.objectives",
            ),
        ),  # fmt: skip
    ],
)
def test_layers_import_one_way(modules, forbidden):
    """Reference: the layering rules of docs/layout.md."""
    for pattern in modules:
        for path in PACKAGE.glob(pattern):
            bad = {m for m in _imports(path) if m.startswith(forbidden)}
            assert not bad, f"{path.name} imports {sorted(bad)}"


def test_no_import_cycle():
    """Reference: a depth-first search over the package's module-level imports."""
    paths = {
        ".".join(p.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__"): p
        for p in PACKAGE.rglob("*.py")
    }
    graph = {}
    for name, path in paths.items():
        deps = set()
        for node in ast.parse(path.read_text()).body:  # module level: the rest is lazy
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("jaxform"):
                # ``from package import submodule`` depends on the submodule
                subs = {f"{node.module}.{a.name}" for a in node.names} & set(paths)
                deps |= subs or {node.module}
        graph[name] = deps
    state = {}

    def visit(m, stack):
        state[m] = "open"
        for d in graph.get(m, ()):
            if state.get(d) == "open":
                raise AssertionError("import cycle: " + " -> ".join([*stack, m, d]))
            if d not in state:
                visit(d, [*stack, m])
        state[m] = "done"

    for m in graph:
        if m not in state:
            visit(m, [])


def test_config_and_kind_branches_stay_in_their_layer():
    """Reference: the architecture issue's rule: ``kind ==`` and ``cfg[`` only in the
    config layer (config, the process's operation tables) and the workpiece layer."""
    for pattern in ("kind ==", "cfg\\["):
        out = subprocess.run(["git", "grep", "-n", pattern, "--", "jaxform"], cwd=ROOT,
                             capture_output=True, text=True).stdout  # fmt: skip
        files = {line.split(":")[0] for line in out.splitlines()}
        allowed = {"jaxform/process_config.py", "jaxform/workpieces.py"}
        assert {f for f in files if not f.startswith("jaxform/config/")} <= allowed, out


def test_init_and_step_take_the_host_loops_steps():
    """Reference: simulate() on the same scene; the caller-owned loop reaches the same
    states (force at every step to 1e-12 relative, the same step sizes)."""
    import jax.numpy as jnp

    # the 3 x 3 seed scene of tests/test_upsetting.py: its chunk program is in the cache
    sc = build_scene(load_config(ROOT / "configs" / "upsetting_seed.toml",
                                 ["mesh.nr=3", "mesh.nz=3", "die.reduction=0.1"]))  # fmt: skip
    ref = simulate(sc).history
    state, control = init(sc)
    forces, dts = [], []
    while float(state.t) < sc.t_end - 1e-9 * sc.dt:
        state, control, info = step(sc, state, control)
        forces.append(info["force_N"])
        dts.append(info["dt_s"])
    np.testing.assert_allclose(forces, ref["force_N"][1:], rtol=1e-12)
    np.testing.assert_allclose(dts, ref["dt_s"][1:], rtol=1e-12)
    # a step that cannot converge (a NaN contact scale) raises at the public boundary
    bad = dataclasses.replace(sc.inputs, c_contact=jnp.asarray(np.nan))
    state, control = init(sc)
    with pytest.raises(SimulationError, match="the step .* failed after 7 attempts"):
        step(sc, state, control, bad)


class _Stream(io.StringIO):
    def __init__(self, tty):
        super().__init__()
        self.tty = tty

    def isatty(self):
        return self.tty


def _row(step, chunk_end):
    return dict(step=step, n_steps=4, chunk_end=chunk_end, time_s=float(step), dt_s=1.0,
                stroke_mm=0.1 * step, force_N=10.0 * step, iterations=3, cutbacks=0)  # fmt: skip


def test_progress_redraws_on_a_terminal_and_logs_chunks_otherwise():
    """Reference: tqdm's in-place redraw (carriage returns) on a terminal; one line per
    compiled chunk (chunk_end) in a log."""
    log = _Stream(False)
    p = Progress(log)
    for k, end in ((1, False), (2, True), (3, False), (4, True)):
        p(_row(k, end))
    p.close()
    lines = log.getvalue().splitlines()
    assert [line.split(":")[0] for line in lines] == ["step 2/4", "step 4/4"]
    assert "\r" not in log.getvalue()
    term = _Stream(True)
    p = Progress(term)
    for k in range(1, 5):
        p(_row(k, k % 2 == 0))
    p.close()
    text = term.getvalue()
    assert "\r" in text and "4/4" in text and "force=40.000 N" in text


def test_config_sections_are_the_schema():
    """Every key of every section class is in the schema with its documentation."""
    from jaxform.config import SCHEMA

    for name, cls in SECTIONS.items():
        assert [f.name for f in dataclasses.fields(cls)] == list(SCHEMA[name])
        assert all(f.doc for f in SCHEMA[name].values())
    assert {f.name for f in dataclasses.fields(Config)} == {s.replace(".", "_") for s in SECTIONS}


def test_no_function_takes_more_than_8_parameters():
    """Reference: the architecture issue's bound (self and keyword-only ones counted)."""
    over = []
    for path in PACKAGE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                a = node.args
                n = len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs)
                n += (a.vararg is not None) + (a.kwarg is not None)
                if n > 8:
                    over.append(f"{path.relative_to(ROOT)}:{node.name} ({n})")
    assert not over, over
