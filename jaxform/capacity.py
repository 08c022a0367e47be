"""Capacity buckets: a scene padded to fixed sizes, so that new meshes reuse one program.

XLA compiles a program for fixed array shapes, and a scene's sizes (nodes, elements,
contact candidates, pattern entries) change with every remesh.  :func:`padded` embeds a
scene in a larger one whose sizes depend only on a *bucket*: the node capacity B (a
geometric grid, :data:`GROWTH`), the candidate capacity C (its own grid) and, from
them, the element and pattern capacities.  Every mesh whose sizes fit the same bucket
gives the same :class:`jaxform.assembly.Layout` and the same argument shapes, so the
compiled step program is reused (jit's cache).  The padding is inert:

* ghost nodes (B - n of them) have every field fixed (Dirichlet rows, value 0); the
  first four form a unit square far from the section where no die reaches, the rest
  sit on its corner;
* ghost elements (B - n_el) are copies of that square: zero displacement, zero stress,
  the material's initial state, no heat exchange, so they add nothing to the residual
  and only fixed rows of the Jacobian;
* ghost contact candidates (C - n_c, at least 2) sit on two ghost nodes, far from every
  die (open contact: zero multipliers), joined by ghost facets of unit length;
* the pattern is padded to ``10 nf^2 B + 16 C + 25 C + dofs`` entries by structural
  zeros in a band between isolated ghost dofs (no duplicates: klujax wants unique
  entries; inside ghost rows: the LU fill stays in the ghost block);
* the index arrays of varying length (Dirichlet dofs, reaction dofs) are padded by
  repeating a ghost dof.

The real unknowns come first in every block (nodes, then candidates, then corner facets),
so :meth:`Padded.state` and :meth:`Padded.trim` move a state between the real and the
padded layout by slicing.  Outputs and remeshing see only the real scene.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from jaxform import mesh as meshing
from jaxform.assembly import Layout, build_indices
from jaxform.contact import Candidates
from jaxform.fields import OUTPUT_FIELDS, FieldMap, map_state
from jaxform.linear import choose_backend
from jaxform.solver import newton_variant

GROWTH = 1.25  # ratio of successive capacities
GRADIENT_GROWTH = 2.0  # the same of the buckets a process's gradient replay pads to
SMALLEST_NODES = 64
SMALLEST_CONTACTS = 16
NONZEROS_PER_NODE = 10  # x nf^2: an all-quad mesh averages about 9 (node and its neighbours)


def grid_value(n: int, smallest: int, growth: float = GROWTH) -> int:
    """The smallest capacity of the grid round(smallest * growth**k / 8) * 8 that is >= n."""
    k = max(0, math.ceil(math.log(max(n, 1) / smallest) / math.log(growth) - 1e-12))
    while True:
        c = int(round(smallest * growth**k / 8.0)) * 8
        if c >= n:
            return c
        k += 1


@dataclass(frozen=True)
class Bucket:
    """The capacities of a padded scene (hashable; equal buckets share a program)."""

    nodes: int
    contacts: int

    def nonzeros(self, n_fields: int, corner: bool) -> int:
        fc = self.contacts if corner else 0
        dofs = self.nodes * n_fields + 2 * self.contacts + fc
        return NONZEROS_PER_NODE * n_fields**2 * self.nodes + 16 * self.contacts + 25 * fc + dofs


@dataclass(frozen=True)
class Padded:
    """A scene padded to a bucket: ``scene`` is what the compiled steps run, ``real`` the
    layout of the scene it pads."""

    scene: object
    real: Layout
    bucket: Bucket

    def _pad_x(self, x, xp=np):
        x = np.asarray(x) if xp is np else x
        cap = self.scene.model.layout
        nodal, lam, facets = self.real.split(x)
        pad = partial(_pad_rows, xp=xp)
        return cap.join(pad(nodal, cap.n_nodes), pad(lam, cap.n_contact),
                        pad(facets, cap.n_facets), xp)  # fmt: skip

    def _trim_x(self, x, xp=np):
        x = np.asarray(x) if xp is np else x
        real = self.real
        nodal, lam, facets = self.scene.model.layout.split(x)
        return real.join(nodal[..., : real.n_nodes, :], lam[..., : real.n_contact, :],
                         facets[..., : real.n_facets], xp)  # fmt: skip

    def coords(self, coords, xp=np):
        """The real scene's reference coordinates with the ghost nodes' after them."""
        ghost = np.asarray(self.scene.inputs.coords)[self.real.n_nodes :]
        return xp.concatenate([coords, ghost])

    def state(self, state, xp=np):
        """The real scene's state in the padded layout (ghosts at rest, initial state),
        field by field as each declares (:mod:`jaxform.fields`).  Host NumPy (so a new
        mesh compiles nothing here), or traced JAX (``xp=jnp``: a gradient run
        differentiates through it)."""
        out = map_state(state, _Pad(self, xp))
        return jax.tree_util.tree_map(jnp.asarray, out) if xp is np else out

    def trim(self, state, xp=np):
        """A padded state in the real scene's layout (host NumPy slices, or traced JAX)."""
        out = map_state(state, _Trim(self, xp, 0))
        return jax.tree_util.tree_map(jnp.asarray, out) if xp is np else out

    def trim_outputs(self, outs: dict) -> dict:
        """A chunk's outputs (host arrays, leading axis the steps) in the real layout."""
        trim = _Trim(self, np, 1)
        out = dict(outs)  # (a chunk that failed singular has no fields)
        for k, kind in OUTPUT_FIELDS.items():
            if k in outs:
                out[k] = getattr(trim, kind.method)(outs[k])
        return out


def _pad_rows(a, n: int, xp=np):
    """``a`` with zero rows after its own to n rows."""
    return xp.concatenate([a, xp.zeros((n - a.shape[0],) + a.shape[1:], a.dtype)])


class _Pad(FieldMap):
    """The fields of a real scene's state in its padded layout: ghost nodes, candidates
    and facets at rest (zeros), ghost elements in the material's initial state."""

    def __init__(self, padded: Padded, xp):
        self.p, self.xp = padded, xp
        self.ghost_el = padded.scene.model.layout.n_elements - padded.real.n_elements

    def _host(self, a):
        return np.asarray(a) if self.xp is np else a

    def unknowns(self, x):
        return self.p._pad_x(x, self.xp)

    rates = unknowns

    def element(self, value, rest=0.0):
        a = self._host(value)
        ghost = np.broadcast_to(np.asarray(rest, a.dtype), (self.ghost_el,) + a.shape[1:])
        return self.xp.concatenate([a, ghost])

    def gauss(self, value):
        model, params = self.p.scene.model, self.p.scene.inputs.params
        with jax.ensure_compile_time_eval():  # constants, also inside a traced run
            init = model.law.initial_state(params)
        rest = type(value)(F=np.eye(3), mat=init)
        return jax.tree_util.tree_map(self.element, value, rest)

    def candidate(self, value):
        n = self.p.scene.model.layout.n_contact
        return _pad_rows(self._host(value), n, self.xp)

    status = candidate


class _Trim(FieldMap):
    """The fields of a padded state in the real scene's layout (``lead`` leading axes
    before the one indexed: 1 for a chunk's outputs, leading axis the steps)."""

    def __init__(self, padded: Padded, xp, lead: int):
        self.p, self.xp, self.lead = padded, xp, lead

    def _part(self, a, n):
        a = np.asarray(a) if self.xp is np else a
        return a[(slice(None),) * self.lead + (slice(0, n),)]

    def unknowns(self, x):
        return self.p._trim_x(x, self.xp)

    rates = unknowns

    def element(self, value):
        return self._part(value, self.p.real.n_elements)

    def gauss(self, value):
        return jax.tree_util.tree_map(self.element, value)

    def candidate(self, value):
        return self._part(value, self.p.real.n_contact)

    status = candidate


def _ghost_die(scene):
    """The die the ghost candidates face (None: no die)."""
    die = scene.inputs.die
    return None if die is None else scene.model.contact.pairing.ghost_die(die)


def _ghost_square(coords: np.ndarray, die=None, t_end: float = 0.0) -> np.ndarray:
    """A unit square far from the section (r > 0: a valid axisymmetric element),
    counter-clockwise, where ``die`` (if any) leaves it open all the run: far below the
    section under its middle (under a top die), else far beside it, else far above, else
    beside it at a height where the top and bottom dies leave a gap."""
    lo, hi = coords.min(axis=0), coords.max(axis=0)
    size = float(np.max(hi - lo))
    far = 10.0 * size + 2.0
    unit = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    corners = [
        np.array([0.5 * (lo[0] + hi[0]) + 0.5, lo[1] - far]),
        np.array([hi[0] + far, lo[1] - far]),
        np.array([hi[0] + far, 0.5 * (lo[1] + hi[1])]),
        np.array([0.5 * (lo[0] + hi[0]) + 0.5, hi[1] + far]),
        # between a top and a bottom die: beside the section at any height
        *(np.array([hi[0] + far, z]) for z in np.linspace(lo[1], hi[1], 41)),
    ]
    if die is None:
        return corners[0] + unit
    from jaxform.rezone import gap_function

    times = np.linspace(0.0, max(t_end, 0.0), 5)
    for c in corners:
        square = c + unit
        if all(np.all(gap_function(die, t)(square)[0] > 1.0) for t in times):
            return square
    raise RuntimeError("no place for the ghost nodes where the die leaves them open")


def _band(ghost_dofs: np.ndarray, count: int, n: int) -> np.ndarray:
    """``count`` keys row * n + col of distinct off-diagonal pairs of ``ghost_dofs``, in
    bands of growing offset.  ValueError when they cannot hold that many."""
    k = len(ghost_dofs)
    if count > k * (k - 1):
        raise ValueError("not enough ghost dofs for the pattern's padding")
    keys, d = [], 1
    while sum(len(a) for a in keys) < count:
        a, b = ghost_dofs[:-d], ghost_dofs[d:]
        keys += [a * n + b, b * n + a]
        d += 1
    return np.concatenate(keys)[:count] if count else np.zeros(0, np.int64)


def bucket_of(scene) -> Bucket:
    """The smallest bucket that holds the scene's sizes with room for the padding."""
    lay = scene.model.layout
    nodes = grid_value(lay.n_nodes + 8, SMALLEST_NODES)
    contacts = grid_value(lay.n_contact + 2, SMALLEST_CONTACTS)
    return Bucket(nodes, contacts)


def coarse_bucket(scene, growth: float = GRADIENT_GROWTH) -> Bucket:
    """:func:`bucket_of` on a grid of ratio ``growth``: the bucket a gradient replay pads a
    mesh to (:meth:`jaxform.process_gradients.ProcessPlan.of`), so that a process's many
    meshes share a few step programs (each compiled twice, with its reverse pass) at the
    price of more padding per step."""
    lay = scene.model.layout
    nodes = grid_value(lay.n_nodes + 8, SMALLEST_NODES, growth)
    return Bucket(nodes, grid_value(lay.n_contact + 2, SMALLEST_CONTACTS, growth))


def padded(scene, bucket: Bucket | None = None) -> Padded:
    """The scene padded to ``bucket`` (default :func:`bucket_of`; the next larger node
    capacity where the pattern's padding does not fit)."""
    bucket = bucket or bucket_of(scene)
    while True:
        try:
            return _padded(scene, bucket)
        except ValueError:
            bucket = Bucket(grid_value(bucket.nodes + 1, SMALLEST_NODES), bucket.contacts)


def _padded(scene, bucket: Bucket) -> Padded:
    real, idx, mesh = scene.model.layout, scene.idx, scene.mesh
    nf, n, n_el, n_c = real.n_fields, real.n_nodes, real.n_elements, real.n_contact
    corner = real.n_facets > 0
    g = np.arange(n, bucket.nodes)  # ghost nodes
    if n_el > bucket.nodes or len(g) < 8 or bucket.contacts < n_c + 2:
        raise ValueError("bucket too small")
    coords = np.vstack(
        [
            np.asarray(scene.inputs.coords),
            np.repeat(
                _ghost_square(mesh.coords, _ghost_die(scene), scene.t_end), [1, 1, 1, len(g) - 3], 0
            ),
        ]
    )
    square = g[:4]
    elements = np.vstack([np.asarray(mesh.elements), np.tile(square, (bucket.nodes - n_el, 1))])
    ghost_mesh = meshing.Mesh(coords, elements, mesh.node_sets, mesh.facet_sets)
    fixed = np.concatenate([np.asarray(idx.fixed), (g[:, None] * nf + np.arange(nf)).ravel()])
    fixed = np.concatenate([fixed, np.full(bucket.nodes * nf - len(fixed), g[0] * nf)])
    ghost_c = np.where(np.arange(bucket.contacts - n_c) % 2 == 0, g[0], g[1])
    contact_nodes = np.concatenate([np.asarray(idx.contact_nodes), ghost_c]).astype(np.int64)
    # the ghosts are candidates of die 0 (where candidates are (node, die) pairs)
    real_die = np.asarray(idx.contact_die, dtype=np.int64)
    contact_die = np.concatenate([real_die, np.zeros(len(ghost_c), np.int64)])
    local = np.asarray(idx.contact_facets, dtype=np.int64).reshape(-1, 2)
    real_facets = np.asarray(idx.contact_nodes)[local]
    n_ghost_f = bucket.contacts - len(real_facets)
    facets = np.vstack([real_facets, np.tile([g[0], g[1]], (n_ghost_f, 1))])
    facet_die = np.concatenate([real_die[local[:, 0]], np.zeros(n_ghost_f, np.int64)])
    reaction = np.asarray(idx.bottom_reaction_dofs)
    reaction = np.concatenate([reaction, np.full(bucket.nodes - len(reaction), g[0] * nf + 1)])
    candidates = Candidates(contact_nodes, facets, contact_die, facet_die)
    layout, pidx = build_indices(ghost_mesh, nf, fixed, candidates, reaction_dofs=reaction,
                                 corner_contact=corner)  # fmt: skip
    layout = replace(layout, temperature=real.temperature)
    pmodel, pidx = replace(scene.model, layout=layout).with_pattern(pidx)
    layout = pmodel.layout
    # the pattern padded to its capacity by a band of zeros between isolated ghost dofs
    cap = bucket.nonzeros(nf, corner)
    n_dofs = layout.n_dofs
    rows, cols, slot = (np.asarray(a, dtype=np.int64) for a in (pidx.rows, pidx.cols, pidx.slot))
    if len(rows) > cap:
        raise ValueError("pattern over capacity")
    isolated = (g[4:, None] * nf + np.arange(nf)).ravel()
    keys = np.sort(np.concatenate([rows * n_dofs + cols, _band(isolated, cap - len(rows), n_dofs)]))
    new_slot = np.searchsorted(keys, (rows * n_dofs + cols)[slot])
    pidx = replace(
        pidx,
        rows=jnp.asarray(keys // n_dofs, dtype=jnp.int32),
        cols=jnp.asarray(keys % n_dofs, dtype=jnp.int32),
        slot=jnp.asarray(new_slot, dtype=jnp.int32),
    )
    layout = replace(layout, n_nonzeros=cap)
    if real.temperature:
        edges = np.zeros((len(elements), 4))
        edges[:n_el] = np.asarray(idx.exposed_edges)
        pidx = replace(pidx, exposed_edges=jnp.asarray(edges))
    so = scene.settings.solver
    linear = choose_backend(so.linear, layout.n_dofs)
    pidx = replace(pidx, lu_symbolic=linear.analyze(pidx.rows, pidx.cols, n_dofs))
    variant = newton_variant(so.newton, linear, n_dofs, so.anderson_depth, remeshes=scene.remeshes)
    newton = replace(scene.newton, variant=variant)
    pscene = replace(
        scene,
        mesh=ghost_mesh,
        model=replace(scene.model, layout=layout),
        idx=pidx,
        linear=linear,
        newton=newton,
        inputs=replace(scene.inputs, coords=jnp.asarray(coords)),
    )
    return Padded(pscene, real, bucket)
