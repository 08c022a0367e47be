"""Where a remesh loses die force: in the carried state, or in the new mesh's response.

Runs a config (with its remeshing) to a time T, then from the state at T takes one
vanishing step (1e-4 of the last step size: the carried state re-balanced, no new flow) and
one step of the last step size, each on the mesh the run ended on, on a new mesh of its
deformed section (:func:`jaxform.remesh.remesh`), on an identity remesh (the same mesh,
the state carried by the same kind of map) and on a new mesh whose boundary nodes are the
old mesh's (gmsh meshes the interior anew).  The die moves on as in the full run.  Each
step's force is split by where the die holds the part: contact nodes and corner facets
between given radii.

    python experiments/remesh_force_loss.py configs/closed_die_flash.toml 47.2 \\
        --set time.dt_s=0.5 --set remesh.from_start=true --set remesh.quality_below=0.5

(docs/remeshing.md, "What a flash-phase remesh loses, step by step").
"""

import argparse
import time
from dataclasses import replace

import jax
import jax.numpy as jnp
import numpy as np

import jaxform.remesh as remeshing
from jaxform.config import load_config
from jaxform.mesh import Mesh, boundary_polygon, polygon_quads
from jaxform.scenes import build_scene
from jaxform.section_mesh import MesherHelp
from jaxform.simulation import init, simulate, step
from jaxform.stepping import facet_normal

jax.config.update("jax_enable_x64", True)


def by_radius(scene, state, edges) -> str:
    """The die force (N, z, compression positive) the contact nodes and the corner facets
    carry, summed between the radii ``edges`` (mm) where they are."""
    model, idx, inp, x, t = scene.model, scene.idx, scene.inputs, state.x, state.t
    pos = model.nodal_positions(x, inp.coords, idx)[idx.contact_nodes]
    frames = model.contact.frames(inp.die, pos, idx.contact_die, t, t)
    lam = x[idx.mult_dofs]
    fz = -np.asarray(lam[:, 0] * frames.n[:, 1] + lam[:, 1] * frames.tan[:, 1])
    r, f_facets, r_facets = np.asarray(pos[:, 0]), np.zeros(0), np.zeros(0)
    if model.layout.n_facets:
        ends = model.facet_ends(x, inp.coords, idx)
        f_facets = np.asarray(x[idx.facet_mult] * facet_normal(ends[:, 0], ends[:, 1])[:, 1])
        r_facets = np.asarray(0.5 * (ends[:, 0, 0] + ends[:, 1, 0]))
    parts = []
    for a, b in zip(edges, edges[1:]):
        nodes = fz[(r >= a) & (r < b)].sum()
        facets = f_facets[(r_facets >= a) & (r_facets < b)].sum()
        parts.append(f"r {a:g}-{b:g}: nodes {nodes:.1f}, facets {facets:.1f}")
    return "; ".join(parts)


def probe(scene, state, h: float, edges) -> dict:
    """One step of size h from ``state`` on ``scene``; its force split by radius."""
    _, control = init(scene)
    control = replace(control, h=jnp.asarray(h), t_end=jnp.asarray(float(state.t) + h))
    new, _, out = step(scene, state, control)
    out["by_radius"] = by_radius(scene, new, edges)
    return out


def identity_mesh(scene, pos, t, settings):
    """The old mesh at its deformed position, as a 'new' mesh (and what the mesher needed:
    nothing), as :func:`jaxform.remesh.new_section_mesh` returns it."""
    m = scene.mesh
    mesh = Mesh(np.asarray(pos, float), np.asarray(m.elements), dict(m.node_sets),
                dict(m.facet_sets))  # fmt: skip
    return mesh, MesherHelp()


def kept_boundary_mesh(scene, pos, t, settings):
    """A new mesh of the deformed section whose boundary nodes are the old mesh's, all of
    them and no others (one segment per boundary edge, one edge halved where Blossom
    needs an even count): the interior is new, the boundary's discretization along the
    dies is the old one's."""
    points, labels, _ = boundary_polygon(scene.mesh, np.asarray(pos, float))
    length = np.linalg.norm(np.roll(points, -1, axis=0) - points, axis=1)
    sizes = np.maximum(length, np.roll(length, 1))
    return polygon_quads(points, labels, sizes), MesherHelp()


def remeshed_with(scene, state, mesher):
    """:func:`jaxform.remesh.remesh` of the state with ``mesher`` in place of its
    new_section_mesh (the state carried by the same map)."""
    real = remeshing.new_section_mesh
    remeshing.new_section_mesh = mesher
    try:
        return remeshing.remesh(scene, state, scene.remesh)
    finally:
        remeshing.new_section_mesh = real


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("config")
    ap.add_argument("time_s", type=float, help="stop the run here (s)")
    ap.add_argument("--set", action="append", default=[], dest="overrides")
    ap.add_argument("--radii", type=float, nargs="+", default=[0, 2.2, 3, 6, 6.45, 6.6, 7.4, 20],
                    help="split the force between these radii (mm)")  # fmt: skip
    a = ap.parse_args()
    scene = build_scene(load_config(a.config, a.overrides))
    start = time.time()
    res = simulate(replace(scene, t_end=a.time_s))
    h = res.history
    print(f"run to {a.time_s} s: {len(h['force_N']) - 1} steps, {len(res.remeshes)} remeshes, "
          f"{time.time() - start:.0f} s; force {h['force_N'][-1]:.1f} N")  # fmt: skip
    sc, st, dt = res.final_scene, res.final_state, float(h["dt_s"][-1])
    new = remeshing.remesh(sc, st, sc.remesh)
    same, kept = (remeshed_with(sc, st, m) for m in (identity_mesh, kept_boundary_mesh))
    cases = {"old mesh": (sc, st), "identity remesh": (same.scene, same.state),
             f"new mesh ({new.scene.mesh.n_nodes} nodes)": (new.scene, new.state),
             f"old boundary, new interior ({kept.scene.mesh.n_nodes} nodes)":
                 (kept.scene, kept.state)}  # fmt: skip
    for label, (s, x) in cases.items():
        for h_step in (1e-4 * dt, dt):
            out = probe(s, x, h_step, a.radii)
            print(f"{label}: step {h_step:.3g} s: force {out['force_N']:.1f} N, "
                  f"{out['iterations']} Newton iterations, {out['cutbacks']} cutbacks\n"
                  f"    {out['by_radius']}")  # fmt: skip


if __name__ == "__main__":
    main()
