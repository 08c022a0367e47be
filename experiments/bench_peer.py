"""Peer benchmark: the same plane-strain J2 punch problem solved by jaxform and by JAX-FEM.

    python experiments/bench_peer.py [--quick] [--meshes 20 50 100] [--peer-python PY]
                                     [--out docs/figures]

Problem (both codes, same mesh): a plane-strain block [0, 10] x [0, 10] mm, n x n equal
bilinear quads, symmetric about x = 0 (u_x = 0) on a frictionless base (u_y = 0), pressed
down by a flat frictionless punch of half-width a = (floor(n/2) + 1/2) h (its corner in the
middle of an element, so the same nodes are under it in both codes), travel 0.02 mm
(0.2 % of the depth) in 10 equal steps.  J2 perfect plasticity, G = 26 GPa, K = 68 GPa,
sigma_y = 100 MPa (the preset ``j2_perfect_100MPa``): at the end the block is yielded
under and beside the punch and the force is within a few % of its plateau.  Force: the
punch force per mm of depth on the half model (N/mm).

* **jaxform** (this repository): the scene is a ``[block]`` config dict (rigid punch
  ``die.profile_mm``, corner radius h/10) run by ``jaxform.simulation.simulate`` -- the real
  code path:
  node-to-die contact by complementarity functions with the contact multipliers as extra
  unknowns, finite strain (updated positions, rotation-neutralized strain increment),
  Newton with backtracking line search and a rate predictor inside one compiled
  ``lax.scan``, klujax sparse LU; ``solver.rtol`` = 1e-8 (||R|| <= 1e-8 x the step's
  force scale).  Elements: ``q4`` (displacement, 2 x 2 Gauss: the peer's element) and
  ``q1p0`` (mean dilatation, what jaxform recommends: q4 locks under plastic flow), with
  ``solver.newton = 'auto'``; ``q4:modified`` runs q4 with modified Newton at every size.
* **JAX-FEM** (``jax_fem``, PyPI ``jax-fem`` 0.0.11; https://github.com/deepmodeling/jax-fem):
  a ``Problem`` subclass with QUAD4 elements (2 x 2 Gauss) whose ``get_tensor_map`` is the
  small-strain radial return of the same J2 law (plane strain: eps_zz = 0; the 3 x 3
  stress and strain of the last converged step as internal variables, updated after each
  step as in JAX-FEM's plasticity demo); the punch is a Dirichlet condition u_y = -d on
  the nodes with x < a (frictionless: u_x free).  Assembly is JAX-FEM's own
  (``Problem.newton_update``: the vmapped jvp-Jacobian of the element kernel in 20 chunks,
  values pulled to the host).  Newton: ``jax_fem.solver.solver`` (row elimination of the
  Dirichlet rows, full steps, no line search, each step starts from the last solution)
  with its SciPy backend ``umfpack_solver`` (``scipy.sparse.linalg.spsolve``: SuperLU
  unless scikit-umfpack is installed); ``tol`` = 1e-8 x sigma_y x a (absolute, N/mm),
  ``rel_tol`` off (1e-30).  ``jax_fem.solver`` imports petsc4py at the top (its
  ``get_A`` builds the matrix as a PETSc Mat even for the SciPy backend); where petsc4py
  is missing the script runs a copy of that Newton loop (``_jaxfem_newton``: the same
  row elimination, stopping test and ``spsolve`` call, the matrix built with SciPy
  instead of PETSc) on JAX-FEM's assembly, and says so (``newton`` in the result).

Physics that differ, and why the answers still agree (checked: ``vs peer``): jaxform is
finite strain, the peer small strain; at 0.2 % travel the forces agree to ~1e-4.
jaxform's punch is a contact condition (plus 2 multiplier unknowns per top node), the
peer's a prescribed displacement: the same for a frictionless flat punch whose nodes
stay in contact.  Newton's stopping tests differ in form (relative to jaxform's force
scale, absolute for the peer), both ~1e-8 of the forces carried; Newton converges
quadratically, so this moves an iteration count by at most one.

Measured per mesh and code, each in its own fresh process (no compile cache shared):
``setup_s`` (scene / Problem set-up), ``compile_s`` (first run minus second run: JIT
compilation), ``solve_s`` (the whole load history again after compilation, best of 2),
``newton_iterations`` (summed over the steps), ``assemblies`` (Jacobians assembled: each
of jaxform's is followed by a factorization, its other iterations reuse a kept one),
``per_iteration_s`` = solve_s / iterations,
and the split of an iteration: jaxform -- its compiled pieces timed separately at the
final state, best of 3 (``assembly_s`` = ``Model.residual_and_jacobian``: element
residuals, their jacfwd Jacobians, contact blocks, scatter onto the pattern;
``element_s`` = the vmapped element jacfwd alone; ``residual_s`` = one line-search trial;
``linear_s`` = one solve by the backend ``solver.linear = 'auto'`` picks, factorization
included: klujax, MKL PARDISO from 20 000 unknowns where installed); JAX-FEM -- wall
time inside its functions during the timed run, per call (``element_s`` =
``Problem.newton_update``, ``assembly_s`` = that plus building the row-eliminated
matrix: one more call per step than iterations, the step's first residual;
``linear_s`` = the linear solve, one per iteration).  Prints a table; writes
``bench_peer.csv``.

Installing the peer (benchmark only, NOT a project dependency; keep it out of the project
environment).  jax-fem 0.0.11 declares no dependencies but imports pyfiglet, basix
(PyPI fenics-basix), gmsh and petsc4py:

    python -m venv /tmp/peervenv --system-site-packages
    /tmp/peervenv/bin/pip install jax-fem pyfiglet fenics-basix gmsh
    python experiments/bench_peer.py --peer-python /tmp/peervenv/bin/python

and for ``jax_fem.solver`` itself also ``pip install petsc petsc4py``.  PETSc has no binary
wheel: pip builds it from source (needs BLAS/LAPACK, e.g. Debian's liblapack-dev, and
``PETSC_CONFIGURE_OPTIONS="--with-fc=0 --with-fortran-bindings=0"`` without gfortran),
twice (once as petsc4py's build dependency); on the shared 2-core machine it did not
finish in 30 minutes, so the numbers in the README use the copy of the Newton loop.
Without the peer the script says so and runs the jaxform side alone.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from functools import partial
from pathlib import Path

import numpy as np
from timing import best_of

ROOT = Path(__file__).resolve().parents[1]
WIDTH = DEPTH = 10.0  # mm
TRAVEL = 0.02  # mm
STEPS = 10
RTOL = 1e-8  # Newton: residual relative to the force scale
REPEATS = 2  # runs after compilation; the fastest counts (the machine is shared)
PRESET = "j2_perfect_100MPa"
MATERIAL = {"G_MPa": 26000.0, "K_MPa": 68000.0, "sigma_y0_MPa": 100.0, "H_MPa": 0.0}
INSTALL = (
    "JAX-FEM is not importable by {py}: the peer side is skipped.  Install it in a "
    "separate venv (see this script's docstring: jax-fem, pyfiglet, fenics-basix, "
    "gmsh, petsc, petsc4py) and pass --peer-python /path/to/venv/bin/python"
)


def geometry(n: int) -> dict:
    h = WIDTH / n
    return {"n": n, "h": h, "a": (n // 2 + 0.5) * h}


def _rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


# ---------------------------------------------------------------------------------------
# jaxform side


def jaxform_config(n: int, element: str) -> dict:
    """The scene for mesh n x n; ``element`` is 'q4' or 'q1p0', or with the Newton method
    after a colon ('q4:modified'; otherwise solver.newton = 'auto')."""
    element, _, newton = element.partition(":")
    g = geometry(n)
    return {
        "block": {
            "width_mm": WIDTH,
            "depth_mm": DEPTH,
            "fine_width_mm": WIDTH,
            "fine_depth_mm": DEPTH,
        },
        "mesh": {"nr": n, "nz": n, "element": element, "geometry": "plane_strain"},
        "material": {"preset": PRESET},
        "die": {
            "profile_mm": [[0.0, DEPTH], [g["a"], DEPTH], [g["a"], DEPTH + 1.0]],
            "speed_mm_s": 1.0,
            "reduction": TRAVEL / DEPTH,
            "corner_radius_mm": 0.1 * g["h"],
        },
        "time": {"dt_s": TRAVEL / STEPS},
        "solver": {
            "rtol": RTOL,
            "linear": "auto",
            "chunk_steps": STEPS,
            "newton": newton or "auto",
        },
        "output": {"fields": False, "plots": False},
    }


def run_jaxform(n: int, element: str, split: bool = True) -> dict:
    import jax

    import jaxform
    from jaxform.config import load_config
    from jaxform.scenes import build_scene
    from jaxform.simulation import simulate
    from jaxform.stepping import step_context

    jaxform.enable_x64()
    cfg = load_config(jaxform_config(n, element))
    t0 = time.perf_counter()
    scene = build_scene(cfg)
    setup = time.perf_counter() - t0
    t0 = time.perf_counter()
    simulate(scene)
    first = time.perf_counter() - t0
    second = np.inf
    for _ in range(REPEATS):
        t0 = time.perf_counter()
        res = simulate(build_scene(cfg))
        second = min(second, time.perf_counter() - t0)
    its = res.history["newton_iterations"][1:]
    lay = scene.model.layout
    out = {
        "code": "jaxform",
        "element": element,
        "n": n,
        "unknowns": int(lay.n_dofs),
        "setup_s": setup,
        "compile_s": first - second,
        "solve_s": second,
        "newton_iterations": int(its.sum()),
        "iterations_per_step": its.tolist(),
        # each factorization follows an assembly of the Jacobian (a refresh)
        "assemblies": int(res.history["factorizations"][1:].sum()),
        "cutbacks": int(res.history["cutbacks"].sum()),
        "per_iteration_s": second / its.sum(),
        "force_N": res.history["force_N"][1:].tolist(),
        "last_residuals": [float(v) for v in res.newton_histories[-1] if np.isfinite(v)],
    }
    if split:  # the compiled pieces of one iteration, at the final state
        model, idx, inp, st = scene.model, scene.idx, scene.inputs, res.final_state
        t = st.t
        dt = jax.numpy.asarray(scene.dt)
        ctx = step_context(model, st, inp, idx, t, dt)
        x = st.x
        rj = jax.jit(model.residual_and_jacobian)
        rf = jax.jit(model.residual)
        sym = idx.lu_symbolic
        solve = jax.jit(lambda r, c, v, b: scene.linear.solve(r, c, v, b, lay.n_dofs, sym))
        r, vals, *_ = rj(x, ctx)

        def element_jacobians(x, ctx):
            term = model.element
            ep = term.residual_pass(x, ctx, model.layout)
            return term.jacobians(term.element_fn(ctx, model.layout), ep, ctx.gauss)

        elem = jax.jit(element_jacobians)
        out["assembly_s"] = best_of(lambda: rj(x, ctx), 3)
        out["element_s"] = best_of(lambda: elem(x, ctx), 3)
        out["residual_s"] = best_of(lambda: rf(x, ctx), 3)
        out["linear_s"] = best_of(lambda: solve(idx.rows, idx.cols, vals, -r), 3)
    out["peak_rss_mib"] = _rss_mib()
    return out


# ---------------------------------------------------------------------------------------
# JAX-FEM side (imported only in the peer's process)


def run_peer(n: int) -> dict:
    import logging

    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_x64", True)
    from jax_fem import logger
    from jax_fem.generate_mesh import Mesh
    from jax_fem.problem import Problem

    logger.setLevel(logging.WARNING)
    import jaxform
    from jaxform.config import load_config
    from jaxform.scenes import build_scene

    jaxform.enable_x64()
    geo = geometry(n)
    mesh_jx = build_scene(load_config(jaxform_config(n, "q4"))).mesh  # the very same mesh
    G, K = MATERIAL["G_MPa"], MATERIAL["K_MPa"]
    SY, H = MATERIAL["sigma_y0_MPa"], MATERIAL["H_MPa"]
    eye = jnp.eye(3)

    def return_map(u_grad, sig_old, eps_old, eqps_old):
        """Small-strain plane-strain J2 radial return (linear isotropic hardening H)."""
        eps = jnp.zeros((3, 3)).at[:2, :2].set(0.5 * (u_grad + u_grad.T))
        de = eps - eps_old
        sig_tr = sig_old + (K - 2.0 * G / 3.0) * jnp.trace(de) * eye + 2.0 * G * de
        s = sig_tr - jnp.trace(sig_tr) / 3.0 * eye
        q2 = 1.5 * jnp.sum(s * s)
        pos = q2 > 0.0
        q = jnp.sqrt(jnp.where(pos, q2, 1.0))
        dg = jnp.maximum(jnp.where(pos, q, 0.0) - (SY + H * eqps_old), 0.0) / (3.0 * G + H)
        sig = sig_tr - jnp.where(pos, 3.0 * G * dg / q, 0.0) * s
        return sig, eps, eqps_old + dg

    class PlaneStrainJ2(Problem):
        def custom_init(self):
            self.reset()

        def reset(self):
            nc, nq = self.fes[0].num_cells, self.fes[0].num_quads
            self.internal_vars = [
                jnp.zeros((nc, nq, 3, 3)),
                jnp.zeros((nc, nq, 3, 3)),
                jnp.zeros((nc, nq)),
            ]

        def get_tensor_map(self):
            return lambda u_grad, *old: return_map(u_grad, *old)[0][:2, :2]

    update = jax.jit(lambda ug, *old: jax.vmap(jax.vmap(return_map))(ug, *old))

    tol_x = 1e-8 * geo["h"]
    coords = np.asarray(mesh_jx.coords)
    top = coords[:, 1].max()

    def bc(d):
        return [
            [
                lambda p: jnp.isclose(p[0], 0.0, atol=tol_x),
                lambda p: jnp.isclose(p[1], 0.0, atol=tol_x),
                lambda p: jnp.isclose(p[1], top, atol=tol_x) & (p[0] < geo["a"]),
            ],
            [0, 1, 1],
            [lambda p: 0.0, lambda p: 0.0, lambda p: -d],
        ]

    t0 = time.perf_counter()
    mesh = Mesh(coords, np.asarray(mesh_jx.elements), ele_type="QUAD4")
    prob = PlaneStrainJ2(
        mesh, vec=2, dim=2, ele_type="QUAD4", gauss_order=2, dirichlet_bc_info=bc(0.0)
    )
    setup = time.perf_counter() - t0
    if np.any(np.asarray(prob.JxW) <= 0):
        raise RuntimeError("peer mesh: non-positive JxW (node order)")
    punch = np.flatnonzero((np.abs(coords[:, 1] - top) < tol_x) & (coords[:, 0] < geo["a"]))

    # wall time inside JAX-FEM's own functions (wrapped, not changed)
    clock = {"assembly_s": 0.0, "element_s": 0.0, "linear_s": 0.0, "iterations": 0, "assemblies": 0}

    def timed(fn, keys, count=None):
        def wrapper(*a, **k):
            t = time.perf_counter()
            r = fn(*a, **k)
            jax.block_until_ready(r)
            for key in keys:
                clock[key] += time.perf_counter() - t
            if count:
                clock[count] += 1
            return r

        return wrapper

    prob.newton_update = timed(prob.newton_update, ("assembly_s", "element_s"), "assemblies")
    options = {
        "umfpack_solver": {},
        "tol": RTOL * MATERIAL["sigma_y0_MPa"] * geo["a"],
        "rel_tol": 1e-30,
    }
    try:
        import jax_fem.solver as fem_solver  # imports petsc4py
    except ImportError as err:
        newton = "own Newton (jax_fem.solver's loop) + scipy spsolve"
        print(
            f"jax_fem.solver not importable ({err}): JAX-FEM's assembly with a copy of its "
            f"Newton loop",
            file=sys.stderr,
        )
        solve = partial(
            _jaxfem_newton,
            prob,
            timed(_row_eliminated, ("assembly_s",)),
            timed(_spsolve, ("linear_s",), "iterations"),
        )
    else:
        newton = "jax_fem.solver.solver, umfpack_solver (scipy spsolve)"
        fem_solver.get_A = timed(fem_solver.get_A, ("assembly_s",))
        fem_solver.linear_solver = timed(fem_solver.linear_solver, ("linear_s",), "iterations")
        solve = partial(fem_solver.solver, prob)

    def history():
        prob.reset()
        sol = jnp.zeros((coords.shape[0], 2))
        forces, its = [], []
        for k in range(1, STEPS + 1):
            prob.fes[0].update_Dirichlet_boundary_conditions(bc(k * TRAVEL / STEPS))
            before = clock["iterations"]
            sol = solve(dict(options, initial_guess=[sol]))[0]
            its.append(clock["iterations"] - before)
            prob.internal_vars = list(update(prob.fes[0].sol_to_grad(sol), *prob.internal_vars))
            reaction = prob.compute_residual([sol])[0]
            forces.append(-float(jnp.sum(reaction[punch, 1])))
        jax.block_until_ready(sol)
        return forces, its

    t0 = time.perf_counter()
    history()
    first = time.perf_counter() - t0
    second, best = np.inf, {}
    for _ in range(REPEATS):
        for key in clock:
            clock[key] = 0
        t0 = time.perf_counter()
        forces, its = history()
        if time.perf_counter() - t0 < second:
            second, best = time.perf_counter() - t0, dict(clock)
    clock = best
    total = int(sum(its))
    return {
        "code": "jax-fem",
        "element": "q4",
        "n": n,
        "newton": newton,
        "unknowns": int(prob.num_total_dofs_all_vars),
        "setup_s": setup,
        "compile_s": first - second,
        "solve_s": second,
        "newton_iterations": total,
        "iterations_per_step": its,
        "cutbacks": 0,
        "per_iteration_s": second / total,
        "force_N": forces,
        "assembly_s": clock["assembly_s"] / clock["assemblies"],
        "element_s": clock["element_s"] / clock["assemblies"],
        "assemblies": clock["assemblies"],
        "linear_s": clock["linear_s"] / total,
        "residual_s": float("nan"),
        "peak_rss_mib": _rss_mib(),
    }


def _row_eliminated(prob, rows):
    """JAX-FEM's global matrix with its Dirichlet rows replaced by identity rows (what
    ``jax_fem.solver.get_A`` builds with PETSc's zeroRows), as a SciPy CSR matrix."""
    import scipy.sparse as sp

    n = prob.num_total_dofs_all_vars
    a = sp.csr_matrix((np.asarray(prob.V), (prob.I, prob.J)), shape=(n, n))
    keep = np.ones(n)
    keep[rows] = 0.0
    return sp.diags(keep) @ a + sp.diags(1.0 - keep)


def _spsolve(a, b):
    import scipy.sparse.linalg as spl

    return spl.spsolve(a, b)


def _jaxfem_newton(prob, matrix, linear, options):
    """jax_fem.solver.solver's Newton loop for one variable without constraints (used only
    where petsc4py, which that module imports, is missing): row elimination of the
    Dirichlet dofs, full Newton steps, stop when ||R|| <= tol or ||R|| / ||R_0|| <= rel_tol."""
    import jax.flatten_util

    fe = prob.fes[0]
    rows = np.concatenate([ni * fe.vec + vi for ni, vi in zip(fe.node_inds_list, fe.vec_inds_list)])
    vals = np.concatenate([np.asarray(v) for v in fe.vals_list])
    dofs = np.asarray(jax.flatten_util.ravel_pytree(options["initial_guess"])[0]).copy()

    def update(dofs):
        res = prob.newton_update(prob.unflatten_fn_sol_list(dofs))
        res = np.asarray(jax.flatten_util.ravel_pytree(res)[0]).copy()
        res[rows] = dofs[rows] - vals
        return res, matrix(prob, rows)

    res, a = update(dofs)
    r0 = np.linalg.norm(res)
    rn = r0
    while rn / r0 > options["rel_tol"] and rn > options["tol"]:
        dofs = dofs + linear(a, -res)
        res, a = update(dofs)
        rn = np.linalg.norm(res)
    if not np.all(np.isfinite(dofs)):
        raise RuntimeError("peer Newton: non-finite solution")
    return prob.unflatten_fn_sol_list(dofs)


# ---------------------------------------------------------------------------------------
# driver


def peer_available(python: str) -> bool:
    p = subprocess.run(
        [python, "-c", "import jax_fem.problem"], capture_output=True, text=True, cwd=ROOT
    )
    return p.returncode == 0


def child(python: str, which: str, n: int, timeout: float, extra=()) -> dict | None:
    """Run one code on one mesh in a fresh process; its result, or None (reason printed)."""
    cmd = [python, str(Path(__file__).resolve()), "--one", which, str(n), *extra]
    try:
        p = subprocess.run(
            cmd,
            capture_output=True,
            text=True,
            cwd=ROOT,
            timeout=timeout,
            env=dict(os.environ, PYTHONPATH=str(ROOT)),
        )
    except subprocess.TimeoutExpired:
        print(f"  {which} {n}x{n}: no result within {timeout:.0f} s")
        return None
    line = [ln for ln in p.stdout.splitlines() if ln.startswith("RESULT ")]
    if p.returncode or not line:
        print(f"  {which} {n}x{n}: failed (exit {p.returncode})\n{p.stderr[-3000:]}")
        return None
    return json.loads(line[-1][7:])


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--meshes", type=int, nargs="+", default=[20, 50, 100])
    ap.add_argument("--quick", action="store_true", help="one small mesh (10 x 10)")
    ap.add_argument(
        "--elements",
        nargs="+",
        default=["q4", "q1p0", "q4:modified"],
        help="jaxform elements to run, each optionally with its solver.newton (q4:modified)",
    )
    ap.add_argument(
        "--peer-python",
        default=os.environ.get("JAXFEM_PYTHON", sys.executable),
        help="Python interpreter that can import jax_fem (default: $JAXFEM_PYTHON or this one)",
    )
    ap.add_argument(
        "--no-split",
        action="store_true",
        help="jaxform: skip timing the compiled pieces (saves 3 compilations)",
    )
    ap.add_argument("--timeout", type=float, default=1800.0, help="seconds per run")
    ap.add_argument("--out", default=str(ROOT / "docs" / "figures"))
    ap.add_argument("--one", nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        which, n = args.one[0], int(args.one[1])
        r = run_peer(n) if which == "jax-fem" else run_jaxform(n, which, not args.no_split)
        print("RESULT " + json.dumps(r), flush=True)
        return 0
    meshes = [10] if args.quick else args.meshes
    have_peer = peer_available(args.peer_python)
    if not have_peer:
        print(INSTALL.format(py=args.peer_python))
    rows = []
    for n in meshes:
        g = geometry(n)
        print(f"{n}x{n}: h = {g['h']:g} mm, punch half-width a = {g['a']:g} mm", flush=True)
        runs = (["jax-fem"] if have_peer else []) + list(args.elements)
        for which in runs:
            py = args.peer_python if which == "jax-fem" else sys.executable
            extra = ["--no-split"] if args.no_split else []
            r = child(py, which, n, args.timeout, extra)
            if r is None:
                continue
            rows.append(r)
            print(
                f"  {which:>11}: F = {r['force_N'][-1]:.3f} N/mm, "
                f"{r['newton_iterations']} iterations {r['iterations_per_step']}, "
                f"setup {r['setup_s']:.2f} s, compile {r['compile_s']:.1f} s, "
                f"solve {r['solve_s']:.3f} s",
                flush=True,
            )
    if not rows:
        return 1
    report(rows, have_peer)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write(rows, out / "bench_peer.csv")
    print(f"wrote {out / 'bench_peer.csv'}")
    return 0


def report(rows: list[dict], have_peer: bool) -> None:
    peer = {r["n"]: r for r in rows if r["code"] == "jax-fem"}
    print(
        f"\n{'mesh':>7} {'code':>20} {'unknowns':>8} {'setup':>7} {'compile':>8} "
        f"{'solve':>8} {'its':>4} {'asm':>4} {'per it':>9} {'assembly':>9} {'element':>8} "
        f"{'linear':>8} "
        f"{'force':>9} {'vs peer':>8} {'time / peer':>11}"
    )
    for r in rows:
        p = peer.get(r["n"])
        dev = ratio = float("nan")
        if p is not None:
            dev = r["force_N"][-1] / p["force_N"][-1] - 1.0
            ratio = r["solve_s"] / p["solve_s"]
        r["force_vs_peer"], r["solve_vs_peer"] = dev, ratio
        name = r["code"] if r["code"] == "jax-fem" else f"jaxform {r['element']}"
        a = r.get("assembly_s", float("nan"))
        lin = r.get("linear_s", float("nan"))
        el = r.get("element_s", float("nan"))
        print(
            f"{r['n']:>3}x{r['n']:<3} {name:>20} {r['unknowns']:>8} {r['setup_s']:>6.2f}s "
            f"{r['compile_s']:>7.1f}s {r['solve_s']:>7.3f}s {r['newton_iterations']:>4} "
            f"{r['assemblies']:>4} {r['per_iteration_s'] * 1e3:>7.1f}ms "
            f"{a * 1e3:>7.1f}ms {el * 1e3:>6.1f}ms "
            f"{lin * 1e3:>6.1f}ms "
            f"{r['force_N'][-1]:>9.3f} {dev:>+8.3%} {ratio:>10.2f}x"
        )
    if not have_peer:
        print("(no peer: the 'vs peer' columns are empty)")


def write(rows: list[dict], path: Path) -> None:
    keys = (
        "n",
        "unknowns",
        "setup_s",
        "compile_s",
        "solve_s",
        "newton_iterations",
        "assemblies",
        "cutbacks",
        "per_iteration_s",
        "assembly_s",
        "element_s",
        "residual_s",
        "linear_s",
        "peak_rss_mib",
        "force_vs_peer",
        "solve_vs_peer",
    )
    with open(path, "w") as f:
        f.write("code,element," + ",".join(keys) + ",force_N\n")
        for r in rows:
            vals = [f"{float(r.get(k, float('nan'))):.6g}" for k in keys]
            f.write(f"{r['code']},{r['element']}," + ",".join(vals) + f",{r['force_N'][-1]:.6f}\n")


if __name__ == "__main__":
    sys.exit(main())
