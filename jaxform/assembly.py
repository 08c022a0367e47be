"""Degrees of freedom, the fixed sparsity pattern, and global residual/Jacobian assembly.

Unknown vector x = [nodal fields (n_nodes * n_fields) | contact multipliers (2 n_contact)
| corner multipliers (n_facets)], node a's field k at a * n_fields + k (fields: u_r, u_z[,
p]); candidate i's normal and tangential multipliers at n_nodes * n_fields + 2 i + (0, 1)
(a candidate is a contact node, or a (node, die) pair: :class:`Candidates`);
facet f's corner-contact multiplier (:func:`jaxform.contact.facet_terms`) after those.

The assembly is a tuple of terms (:attr:`Model.terms`): the element term (the
formulation with the material law, :class:`ElementTerm`; with a temperature field the
:class:`HeatTerm` that wraps it), node contact, facet (corner) contact, the load and the
fixed (Dirichlet) rows.  Each term declares the unknowns of its blocks (``dofs``: its
part of the sparsity pattern), its part of the residual and its Jacobian blocks; the
global pattern and the value vector are the concatenation over the same tuple, so they
cannot drift apart.  Set-up (NumPy, once per mesh): :func:`build_indices` gives the
:class:`Indices` (element dof maps, Dirichlet dofs, contact candidates),
:meth:`Model.with_pattern` the *unique* pattern holding every entry any term can ever
produce, with the map from each raw entry to its unique slot.  Contact changes never
change the pattern.

In jit: element residuals are vmapped over elements; their Jacobians come from
``jax.jacfwd`` of the same function (no hand-derived tangent), and every term's blocks
are summed into the pattern with one segment_sum.  Dirichlet rows become identity rows.

The assembly is two passes.  The residual pass vmaps the element function over all
elements at once: it gives R and the new Gauss state, and the material's local solves
(the nested Anand roots) run vectorized over every Gauss point of the mesh.  The Jacobian
pass then differentiates the element function at that state (``solution``: each material
update takes the converged point it is given instead of solving again, and differentiates
there, :mod:`jaxform.materials.base`), so its forward-mode tangents run no solver loop.
Same Jacobian as differentiating straight through the solving residual (tested at 1e-11).

The Jacobian pass runs in chunks of ``Model.jacobian_chunk`` elements (a ``lax.map`` over
chunks, each chunk vmapped; the element list is padded with copies of element 0 to a
multiple of the chunk, so one body is compiled): the jacfwd intermediates of all elements
at once (12 tangents x 4 Gauss points x 3 x 3 per element) fall out of cache, and tiny
chunks pay a per-operation overhead (the chunk size was chosen by measurement: the
documentation's benchmarks page, "Measurements behind the code").  The values are the
same as one vmap up to summation order.

External (dead) loads enter as a given force vector: R = f_int + contact - f_ext
(:mod:`jaxform.loads`).  A scene without contact candidates (n_contact = 0, e.g. a clamped
membrane under a traction) has no multipliers and no die: the contact terms are left out
of the compiled program altogether.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxform import element as el
from jaxform.contact import TOUCH_GAP_MM, Candidates, ContactLaw, ContactStep, facet_terms
from jaxform.formulations import Formulation, GaussState, PointGiven
from jaxform.heat import ElementHeat, ThermalInputs, element_heat, plastic_work
from jaxform.mesh import boundary_edges
from jaxform.status import NO_TEMPERATURE, NOT_FINITE


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class Indices:
    """Integer set-up arrays, passed into jit as arguments."""

    edofs: jax.Array  # (n_el, 4 * nf)
    elements: jax.Array  # (n_el, 4) node ids
    fixed: jax.Array  # (n_fixed,) Dirichlet dofs (value 0)
    contact_nodes: jax.Array  # (n_c,)
    contact_dofs: jax.Array  # (n_c, 2) u dofs of the candidates
    mult_dofs: jax.Array  # (n_c, 2) normal and tangential multipliers
    # (n_f, 2) free-surface facets a -> b as the boundary walks them (material on the
    # left), as indices into contact_nodes
    contact_facets: jax.Array
    contact_fixed: jax.Array  # (n_c, 2) bool: the candidate's u_r, u_z are Dirichlet dofs
    facet_dofs: jax.Array  # (n_fc, 4) u dofs of the corner-contact facets' nodes a, b
    facet_mult: jax.Array  # (n_fc,) their multipliers' dofs
    rows: jax.Array  # (n_nz,) unique pattern
    cols: jax.Array
    slot: jax.Array  # (n_raw,) raw entry -> unique slot
    bottom_reaction_dofs: jax.Array  # (n,) u_z dofs on the symmetry plane (for checks)
    load_facets: jax.Array  # (n_lf, 2) node ids of the facets carrying a traction load
    # uint64 handle of the pattern's KLU symbolic analysis (jaxform.klu.symbolic),
    # set by the scene for the sparse backend; None: the solver analyses per solve
    lu_symbolic: jax.Array | None = None
    # (n_el, 4) 1.0 where element edge k exchanges heat (jaxform.heat.exposed_edges);
    # None without a temperature field
    exposed_edges: jax.Array | None = None
    # (n_c,) the die of each candidate where candidates are (node, die) pairs
    # (:class:`jaxform.contact.EachDie`); zeros where each faces its nearest die
    contact_die: jax.Array | None = None


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class StepContext:
    """Everything a step's residual reads besides the unknowns x (a PyTree, traced; built
    once per step by :func:`jaxform.stepping.step_context`)."""

    gauss: GaussState  # converged Gauss state at the start of the step
    coords: jax.Array  # reference nodal coordinates (mm)
    t: jax.Array  # time at the end of the step (s)
    dt: jax.Array  # step size (s)
    params: object  # material parameters
    die: object  # the rigid die (jaxform.dies.RigidDie) or None
    c_contact: jax.Array  # complementarity scale (N/mm)
    cstep: ContactStep | None  # contact constants of the step (None: no candidates)
    idx: Indices
    f_ext: jax.Array | None = None  # external nodal forces at t (N), or None
    thermal: ThermalInputs | None = None  # None: isothermal (no temperature field)
    heat: ElementHeat | None = None  # the step's thermal data per element (with thermal)


@dataclass(frozen=True)
class Layout:
    """Static sizes (hashable: part of the compiled program's identity)."""

    n_nodes: int
    n_fields: int
    n_contact: int
    n_elements: int
    n_nonzeros: int
    n_facets: int = 0  # facets with a corner-contact multiplier
    temperature: bool = False  # the last nodal field is the temperature change (K)

    @property
    def pressure_column(self) -> int | None:
        """The nodal field of the q1q1 pressure (MPa), or None."""
        return 2 if self.n_fields - self.temperature == 3 else None

    @property
    def temperature_column(self) -> int | None:
        """The nodal field of the temperature change from the billet's (K), or None."""
        return self.n_fields - 1 if self.temperature else None

    @property
    def n_mult(self) -> int:
        """Number of multipliers (node contact and corner contact)."""
        return 2 * self.n_contact + self.n_facets

    def node_multipliers(self, x):
        """(n_contact, 2) normal and tangential multipliers of the contact candidates."""
        return self.split(x)[1]

    @property
    def n_node_dofs(self) -> int:
        return self.n_nodes * self.n_fields

    @property
    def n_dofs(self) -> int:
        return self.n_node_dofs + self.n_mult

    def temperatures(self, x, billet_temperature_K):
        """(n_nodes,) nodal temperatures (K) of x (NumPy or JAX), or None without a
        temperature field: the unknown is the change from the billet temperature."""
        if not self.temperature:
            return None
        return billet_temperature_K + self.nodal(x)[:, -1]

    def nodal(self, x):
        """The nodal block of x, (n_nodes, n_fields): u_r, u_z[, p][, T] per node (a view for
        NumPy arrays)."""
        return self.split(x)[0]

    def split(self, x):
        """x (..., n_dofs) in its blocks: (nodal fields (..., n_nodes, n_fields), the
        candidates' normal and tangential multipliers (..., n_contact, 2), the corner
        facets' multipliers (..., n_facets)); leading axes kept, NumPy views or JAX.  With
        :meth:`join` the one place that knows the layout of x."""
        lead, a = x.shape[:-1], self.n_node_dofs
        b = a + 2 * self.n_contact
        return (
            x[..., :a].reshape(lead + (self.n_nodes, self.n_fields)),
            x[..., a:b].reshape(lead + (self.n_contact, 2)),
            x[..., b : b + self.n_facets],
        )

    def join(self, nodal, node_multipliers, facet_multipliers, xp=np):
        """The vector x (..., n_dofs) of its blocks (as :meth:`split` gives them)."""
        lead = nodal.shape[:-2]
        return xp.concatenate(
            [
                nodal.reshape(lead + (self.n_node_dofs,)),
                node_multipliers.reshape(lead + (2 * self.n_contact,)),
                facet_multipliers,
            ],
            axis=-1,
        )


def _device_int32(a) -> jax.Array:
    """An index array on the device as int32, converted on the host and put there by
    ``jax.device_put`` (``jnp.asarray`` of a host array compiles, or loads, a small copy
    program per shape and dtype; so does a conversion on the device)."""
    return jax.device_put(np.asarray(a, dtype=np.int32))


def build_indices(
    mesh,
    n_fields: int,
    fixed_dofs: np.ndarray,
    candidates: Candidates,
    reaction_dofs: np.ndarray | None = None,
    load_facets: np.ndarray | None = None,
    corner_contact: bool = False,
) -> tuple[Layout, Indices]:
    """(Layout, Indices) of a mesh's unknowns, without the sparsity pattern (that is the
    terms', :meth:`Model.with_pattern`).  candidates: the contact candidates and the
    free-surface facets (with ``corner_contact`` each facet of die 0 also gets a
    corner-contact multiplier); load_facets: (n_lf, 2) node pairs of the boundary carrying
    a traction load."""
    nf = n_fields
    n_nodes = mesh.n_nodes
    elements = np.asarray(mesh.elements, dtype=np.int64)
    edofs = (elements[:, :, None] * nf + np.arange(nf)[None, None, :]).reshape(len(elements), -1)
    contact_nodes = np.asarray(candidates.nodes, dtype=np.int64)
    die, facet_die = candidates.dies()
    n_c = len(contact_nodes)
    ndof_nodes = n_nodes * nf
    cdofs = contact_nodes[:, None] * nf + np.arange(2)[None, :]
    mdofs = ndof_nodes + np.arange(2 * n_c).reshape(n_c, 2)
    walked = _oriented(elements, candidates.facets)
    corner = walked[facet_die == 0] if corner_contact else np.zeros((0, 2), int)
    n_fc = len(corner)
    fdofs = (corner[:, :, None] * nf + np.arange(2)[None, None, :]).reshape(n_fc, 4)
    fmult = ndof_nodes + 2 * n_c + np.arange(n_fc)
    layout = Layout(n_nodes, nf, n_c, len(elements), 0, n_fc)
    empty = _device_int32(np.zeros(0, np.int64))
    idx = Indices(
        edofs=_device_int32(edofs),
        elements=_device_int32(elements),
        fixed=_device_int32(np.asarray(fixed_dofs, dtype=np.int64)),
        contact_nodes=_device_int32(contact_nodes),
        contact_dofs=_device_int32(cdofs),
        mult_dofs=_device_int32(mdofs),
        contact_facets=_device_int32(_local_facets(contact_nodes, die, walked, facet_die)),
        contact_fixed=jax.device_put(np.isin(cdofs[:, :2], np.asarray(fixed_dofs))),
        facet_dofs=_device_int32(fdofs),
        facet_mult=_device_int32(fmult),
        rows=empty,
        cols=empty,
        slot=empty,
        bottom_reaction_dofs=_device_int32(
            reaction_dofs if reaction_dofs is not None else np.zeros(0, np.int64)
        ),
        load_facets=_device_int32(
            np.zeros((0, 2), np.int64)
            if load_facets is None
            else np.asarray(load_facets, dtype=np.int64)
        ),
        contact_die=_device_int32(die),
    )
    return layout, idx


def _oriented(elements: np.ndarray, facets) -> np.ndarray:
    """The facets (node pairs) ordered as the boundary walks them (the material on the
    left, :func:`jaxform.mesh.boundary_edges`)."""
    facets = np.asarray(facets if facets is not None else np.zeros((0, 2)), dtype=np.int64)
    walked = boundary_edges(elements)
    n = int(max(np.max(elements, initial=0), np.max(facets, initial=0))) + 1
    forward = np.isin(facets[:, 0] * n + facets[:, 1], walked[:, 0] * n + walked[:, 1])
    return np.where(forward[:, None], facets, facets[:, ::-1]).reshape(-1, 2)


def _local_facets(contact_nodes, die, facets, facet_die) -> np.ndarray:
    """The facets (node pairs) as indices into the candidates: each end the candidate of
    that node and of the facet's die."""
    if facets is None or len(facets) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    n = int(max(contact_nodes.max(), np.max(facets))) + 1
    n_die = int(max(die.max(), facet_die.max())) + 1
    local = -np.ones(n_die * n, dtype=np.int64)
    local[die * n + contact_nodes] = np.arange(len(contact_nodes))
    out = local[facet_die[:, None] * n + np.asarray(facets, dtype=np.int64)]
    if np.any(out < 0):
        raise ValueError("contact facets must join contact candidate nodes")
    return out


def _blocks_pattern(dofs: np.ndarray):
    """(rows, cols) of the dense k x k blocks over the dof lists ``dofs`` (n_blocks, k),
    each block row-major: the order of a (n_blocks, k, k) array's ravel."""
    k = dofs.shape[1]
    rows = np.repeat(dofs[:, :, None], k, axis=2).ravel()
    cols = np.repeat(dofs[:, None, :], k, axis=1).ravel()
    return rows, cols


class ElementPass(NamedTuple):
    """The element term's pass over all elements at x: the gathered dofs, the element
    data, the element residuals r_e, the new Gauss state, the status codes, the heat
    scales, and (a Jacobian pass) the element Jacobian blocks k_e (else None)."""

    xe: jax.Array
    elem: tuple
    r_e: jax.Array
    gauss: GaussState
    code: jax.Array
    heat: jax.Array
    k_e: jax.Array | None = None


# -- terms --------------------------------------------------------------------------
# A term of the assembly (static, hashable) declares
#   dofs(idx) -> (n_blocks, k): the unknowns of each of its blocks: its Jacobian entries
#       are the k x k blocks over them (the sparsity pattern, :meth:`Model.with_pattern`);
#   jacobian(x, ctx, ep) -> (n_blocks, k, k): the values of those blocks (by jax.jacfwd);
#   add_residual(r, x, ctx, ep) -> r: the global residual with its part;
#   scale(x, ctx, ep, lay) -> (): its force scale (N; mJ for heat), 0 for none;
#   multipliers(x, idx) -> (m,): its multipliers (their norm is one force scale);
#   constrain(vals, idx, n) -> vals: the Jacobian values after its rows' conditions.
# The global pattern and value vector are the concatenation of the terms' blocks in the
# order of :attr:`Model.terms`, so the pattern cannot drift from the values.


class _Term:
    """Defaults of a term: no multipliers, no scale, no conditions on the Jacobian."""

    def multipliers(self, x, idx: Indices):
        return jnp.zeros(0, x.dtype)

    def scale(self, x, ctx: StepContext, ep: ElementPass, lay: Layout):
        return jnp.zeros((), x.dtype)

    def constrain(self, vals, idx: Indices, n: int):
        return vals


class _Elements(_Term):
    """What the element terms share: the element dofs' blocks, the residual pass (one
    vmap over the elements) and the Jacobian pass (vmapped jacfwd in chunks)."""

    def dofs(self, idx: Indices):
        return idx.edofs

    def jacobian(self, x, ctx: StepContext, ep: ElementPass):
        return ep.k_e

    def add_residual(self, r, x, ctx: StepContext, ep: ElementPass):
        return r.at[ctx.idx.edofs].add(ep.r_e)

    def residual_pass(self, x, ctx: StepContext, lay: Layout) -> ElementPass:
        """The residual pass: r_e, new Gauss state, codes, heat scales of every element,
        one vmap (the material's local solves run vectorized over the whole mesh)."""
        fn = self.element_fn(ctx, lay)
        xe, elem = x[ctx.idx.edofs], self.element_data(ctx)
        r_e, (_, gnew, ok_e, heat_e) = jax.vmap(fn)(xe, elem, ctx.gauss)
        return ElementPass(xe, elem, r_e, gnew, ok_e, heat_e)

    def jacobians(self, fn, ep: ElementPass, gstate):
        """vmap(jacfwd(fn, has_aux=True)) over the elements, in chunks of
        ``jacobian_chunk`` (see the module docstring), at the new Gauss state of the
        residual pass ``ep`` (no local solve is repeated); returns what the plain vmap
        returns (for the element function: (k_e, aux))."""
        jac = jax.vmap(jax.jacfwd(fn, has_aux=True))
        xe, elem, solution = ep.xe, ep.elem, ep.gauss
        n_el, b = xe.shape[0], self.jacobian_chunk
        if b <= 0 or n_el <= b:
            return jac(xe, elem, gstate, solution)
        n_pad = -n_el % b

        def chunked(a):  # pad with copies of element 0 (a valid element), split in chunks
            if n_pad:
                a = jnp.concatenate([a, jnp.broadcast_to(a[:1], (n_pad,) + a.shape[1:])])
            return a.reshape((-1, b) + a.shape[1:])

        out = jax.lax.map(
            lambda c: jac(*c), jax.tree_util.tree_map(chunked, (xe, elem, gstate, solution))
        )
        return jax.tree_util.tree_map(lambda a: a.reshape((-1,) + a.shape[2:])[:n_el], out)

    def force_scale(self, ep: ElementPass, lay: Layout):
        """The element forces' scale: the norm of the displacement rows of r_e (N)."""
        r_u_e = ep.r_e.reshape(ep.r_e.shape[0], 4, lay.n_fields)[:, :, :2]
        return jnp.sqrt(jnp.sum(r_u_e**2))


@dataclass(frozen=True)
class ElementTerm(_Elements):
    """The element mechanics: the formulation's residual of each element with the
    material law; the Jacobian blocks by jacfwd of the same function."""

    formulation: Formulation
    law: object
    jacobian_chunk: int = 512  # elements per chunk of the element Jacobians; 0: one vmap

    def mechanics(self, ctx: StepContext, x_ref, dofs, gstate, given: PointGiven):
        """(r (4, n_fields of the mechanics), new Gauss state, code) of one element."""
        form = self.formulation
        return form.residual(self.law, ctx.params, ctx.dt, x_ref, dofs, gstate, given)

    def element_fn(self, ctx: StepContext, lay: Layout):
        """The element function of the step: (dofs, (x_ref, heat), Gauss state[,
        solution]) -> (r_e, aux), aux = (r_e, new Gauss state, code, heat scale (4,))."""

        def fn(dofs_flat, elem, gstate, solution=None):
            x_ref, _ = elem
            dofs = dofs_flat.reshape(4, lay.n_fields)
            r, gnew, code = self.mechanics(ctx, x_ref, dofs, gstate, PointGiven(solution))
            return r.ravel(), (r.ravel(), gnew, code, jnp.zeros(4, dofs.dtype))

        return fn

    def element_data(self, ctx: StepContext):
        """What each element's function reads besides its dofs and Gauss state."""
        return ctx.coords[ctx.idx.elements], None

    def scale(self, x, ctx: StepContext, ep: ElementPass, lay: Layout):
        return self.force_scale(ep, lay)

    def heat_flows(self, x, ctx: StepContext, gnew: GaussState, lay: Layout):
        """No heat flows without a temperature field: (4,) zeros."""
        return jnp.zeros(4, dtype=x.dtype)

    def step_heat(self, lay: Layout, x, t, inp, idx: Indices, t_new):
        """No thermal data without a temperature field."""
        return None

    def die_temperature(self, thermal, t, otherwise):
        """The die temperature (K) at t: without a temperature field, ``otherwise``."""
        return otherwise

    def temperatures(self, lay: Layout, x, thermal):
        """No nodal temperatures without a temperature field."""
        return None


@dataclass(frozen=True)
class HeatTerm(_Elements):
    """The element mechanics coupled with the heat balance of each element
    (:mod:`jaxform.heat`): the last nodal field is the temperature change theta (K); the
    mechanics see the Gauss-point temperatures, the heat rows the plastic work; one
    element function, so jacfwd gives the coupled blocks."""

    mechanics: ElementTerm

    @property
    def jacobian_chunk(self) -> int:
        return self.mechanics.jacobian_chunk

    def element_fn(self, ctx: StepContext, lay: Layout):
        """The coupled element function (as :meth:`ElementTerm.element_fn`), its last
        row block the heat of the step (mJ)."""
        dt, th, axi = ctx.dt, ctx.thermal, self.mechanics.formulation.axisymmetric

        def fn(dofs_flat, elem, gstate, solution=None):
            x_ref, heat = elem
            dofs = dofs_flat.reshape(4, lay.n_fields)
            theta = dofs[:, -1]  # the change from the billet temperature (K)
            temp = th.billet_temperature_K + theta
            given = PointGiven(solution, el.N_GP @ temp)
            r, gnew, code = self.mechanics.mechanics(ctx, x_ref, dofs[:, :-1], gstate, given)
            work = plastic_work(gstate.mat, gnew.mat)
            terms = element_heat(th, dt, x_ref, dofs[:, :2], theta, heat, work, axi)
            # thermal rows: the heat of the step (mJ = N mm), like forces in N for mm parts
            r = jnp.concatenate([r, dt * terms.residual()[:, None]], axis=1)
            code = jnp.maximum(code, jnp.where(jnp.all(temp > 0.0), 0, NO_TEMPERATURE))
            return r.ravel(), (r.ravel(), gnew, code, dt * terms.magnitude())

        return fn

    def element_data(self, ctx: StepContext):
        return ctx.coords[ctx.idx.elements], ctx.heat

    def scale(self, x, ctx: StepContext, ep: ElementPass, lay: Layout):
        # the heat of the step (mJ): what the thermal rows carry
        return jnp.maximum(self.force_scale(ep, lay), jnp.sqrt(jnp.sum(ep.heat**2)))

    def heat_flows(self, x, ctx: StepContext, gnew: GaussState, lay: Layout):
        """(4,) the heat of a converged step (mJ): stored, generated by plastic work,
        given to the dies, given to the air; stored = plastic - dies - air at
        convergence."""
        axi = self.mechanics.formulation.axisymmetric
        nodal = lay.nodal(x)[ctx.idx.elements]  # (n_el, 4, n_fields)
        x_ref, heat = self.element_data(ctx)

        def one(x_e, u, theta, h, old, new):
            work = plastic_work(old, new)
            terms = element_heat(ctx.thermal, ctx.dt, x_e, u, theta, h, work, axi)
            return jnp.stack([jnp.sum(terms.stored), jnp.sum(terms.plastic),
                              jnp.sum(terms.die), jnp.sum(terms.air)])  # fmt: skip

        per_el = jax.vmap(one)(x_ref, nodal[..., :2], nodal[..., -1], heat, ctx.gauss.mat, gnew.mat)
        return ctx.dt * per_el.sum(axis=0)

    def step_heat(self, lay: Layout, x, t, inp, idx: Indices, t_new) -> ElementHeat:
        """The thermal data of each element for a step from (x, t) to t_new: nodal
        temperature changes at t, exposed edges, and the edges whose two nodes touch a
        die at t (gap <= TOUCH_GAP_MM, as for shear friction; none before the end of the
        dwell, ``thermal.dwell_s``), the die temperature at t_new."""
        theta_old = lay.nodal(x)[:, -1][idx.elements]
        touching = jnp.zeros(lay.n_nodes, dtype=bool)
        if inp.die is not None and lay.n_contact:
            pos = (inp.coords + lay.nodal(x)[:, :2])[idx.contact_nodes]
            gaps = jax.vmap(lambda p: inp.die.gap(p, t)[0])(pos)
            after_dwell = t >= inp.thermal.dwell_s * (1.0 - 1e-9)  # in air before
            touching = touching.at[idx.contact_nodes].set((gaps <= TOUCH_GAP_MM) & after_dwell)
        nodes = touching[idx.elements]
        touch = (nodes & jnp.roll(nodes, -1, axis=1)).astype(theta_old.dtype)
        die_k = jnp.broadcast_to(inp.thermal.die_temperature(t_new), touch.shape[:1])
        return ElementHeat(theta_old=theta_old, exposed=idx.exposed_edges, touch=touch,
                           die_K=die_k)  # fmt: skip

    def die_temperature(self, thermal, t, otherwise):
        """The die temperature (K) at t of the thermal inputs."""
        return thermal.die_temperature(t)

    def temperatures(self, lay: Layout, x, thermal):
        """(n_nodes,) nodal temperatures (K) of x."""
        return lay.temperatures(x, thermal.billet_temperature_K)


@dataclass(frozen=True)
class NodeContact(_Term):
    """Node-to-die contact of each candidate (:class:`jaxform.contact.ContactLaw`): its
    block is (u_r, u_z, lambda_n, lambda_t)."""

    law: ContactLaw
    layout: Layout

    def dofs(self, idx: Indices):
        return np.concatenate([idx.contact_dofs, idx.mult_dofs], axis=1)

    def _fn(self, ctx: StepContext):
        def fn(v, k):  # v = (x_r, x_z, lambda_n, lambda_t) of candidate k
            r_u, comp = self.law.pair_terms(
                ctx.die, v[:2], v[2:], ctx.t, ctx.c_contact, ctx.cstep, k
            )
            return jnp.concatenate([r_u, comp])

        return fn

    def variables(self, x, ctx: StepContext):
        """(n_c, 4) current positions and multipliers of the candidates."""
        idx = ctx.idx
        pos = (ctx.coords + self.layout.nodal(x)[:, :2])[idx.contact_nodes]
        return jnp.concatenate([pos, x[idx.mult_dofs]], axis=1)

    def jacobian(self, x, ctx: StepContext, ep: ElementPass):
        n_c = self.layout.n_contact
        return jax.vmap(jax.jacfwd(self._fn(ctx)))(self.variables(x, ctx), jnp.arange(n_c))

    def add_residual(self, r, x, ctx: StepContext, ep: ElementPass):
        idx = ctx.idx
        rc = jax.vmap(self._fn(ctx))(self.variables(x, ctx), jnp.arange(self.layout.n_contact))
        return r.at[idx.contact_dofs].add(rc[:, :2]).at[idx.mult_dofs].set(rc[:, 2:])

    def multipliers(self, x, idx: Indices):
        return x[idx.mult_dofs].ravel()

    def report(self, x, ctx: StepContext):
        """Per candidate at a converged x: (status 0/1/2, normal, tangent, slip
        increment)."""
        return jax.vmap(
            lambda vk, k: self.law.pair_status(
                ctx.die, vk[:2], vk[2:], ctx.t, ctx.c_contact, ctx.cstep, k
            )
        )(self.variables(x, ctx), jnp.arange(self.layout.n_contact))


@dataclass(frozen=True)
class FacetContact(_Term):
    """Corner contact of each free-surface facet (:func:`jaxform.contact.facet_terms`, by
    the law's :attr:`~jaxform.contact.ContactLaw.facets_by_node_depth`): its block is
    (u of a, u of b, mu)."""

    law: ContactLaw
    layout: Layout

    def dofs(self, idx: Indices):
        return np.concatenate([idx.facet_dofs, idx.facet_mult[:, None]], axis=1)

    def _terms(self, x, ctx: StepContext, derivative: bool):
        idx, lay = ctx.idx, self.layout
        nodes = idx.facet_dofs[:, ::2] // lay.n_fields
        pos = (ctx.coords + lay.nodal(x)[:, :2])[nodes].reshape(-1, 4)
        v = jnp.concatenate([pos, x[idx.facet_mult][:, None]], axis=1)

        def fn(vf):
            by_depth = self.law.facets_by_node_depth
            return facet_terms(ctx.die, vf, ctx.t, ctx.c_contact, by_depth)

        return jax.vmap(jax.jacfwd(fn) if derivative else fn)(v)

    def jacobian(self, x, ctx: StepContext, ep: ElementPass):
        return self._terms(x, ctx, True)

    def add_residual(self, r, x, ctx: StepContext, ep: ElementPass):
        idx = ctx.idx
        rf = self._terms(x, ctx, False)
        return r.at[idx.facet_dofs].add(rf[:, :4]).at[idx.facet_mult].set(rf[:, 4])

    def multipliers(self, x, idx: Indices):
        return x[idx.facet_mult]


@dataclass(frozen=True)
class Load(_Term):
    """The dead load ctx.f_ext (N; None: no load): R = ... - f_ext; no Jacobian entries."""

    def dofs(self, idx: Indices):
        return np.zeros((0, 0), np.int64)

    def jacobian(self, x, ctx: StepContext, ep: ElementPass):
        return jnp.zeros((0, 0, 0), x.dtype)

    def add_residual(self, r, x, ctx: StepContext, ep: ElementPass):
        return r if ctx.f_ext is None else r - ctx.f_ext

    def scale(self, x, ctx: StepContext, ep: ElementPass, lay: Layout):
        return jnp.zeros((), x.dtype) if ctx.f_ext is None else jnp.linalg.norm(ctx.f_ext)


@dataclass(frozen=True)
class FixedRows(_Term):
    """Dirichlet conditions (value 0): the fixed dofs' residual rows are x there, their
    Jacobian rows identity rows; its blocks are the diagonal of every unknown (so that
    the identity rows and the multiplier rows' diagonal are in the pattern)."""

    n_dofs: int

    def dofs(self, idx: Indices):
        return np.arange(self.n_dofs)[:, None]

    def jacobian(self, x, ctx: StepContext, ep: ElementPass):
        return jnp.zeros(self.n_dofs, x.dtype)

    def add_residual(self, r, x, ctx: StepContext, ep: ElementPass):
        return r.at[ctx.idx.fixed].set(x[ctx.idx.fixed])

    def constrain(self, vals, idx: Indices, n: int):
        fixed_row = jnp.zeros(n, dtype=bool).at[idx.fixed].set(True)
        is_fixed = fixed_row[idx.rows]
        return jnp.where(is_fixed, jnp.where(idx.rows == idx.cols, 1.0, 0.0), vals)


@dataclass(frozen=True)
class Model:
    """The assembly (static, hashable): the element formulation and material law, the
    contact law, the sizes; :attr:`terms` the tuple of terms it assembles."""

    formulation: Formulation
    law: object
    layout: Layout
    contact: ContactLaw = ContactLaw()
    jacobian_chunk: int = 512  # elements per chunk of the element Jacobians; 0: one vmap

    @property
    def element(self):
        """The element term: the mechanics (:class:`ElementTerm`), coupled with heat
        (:class:`HeatTerm`) where the layout has a temperature field."""
        mechanics = ElementTerm(self.formulation, self.law, self.jacobian_chunk)
        return HeatTerm(mechanics) if self.layout.temperature else mechanics

    @property
    def terms(self) -> tuple:
        """The terms in assembly order: element, node contact (with candidates), facet
        contact (with corner contact), load, fixed rows."""
        lay = self.layout
        return (
            self.element,
            *((NodeContact(self.contact, lay),) if lay.n_contact else ()),
            *((FacetContact(self.contact, lay),) if lay.n_facets else ()),
            Load(),
            FixedRows(lay.n_dofs),
        )

    def with_pattern(self, idx: Indices) -> tuple[Model, Indices]:
        """(the model with its number of nonzeros, the indices with the pattern): the
        *unique* entries of every term's blocks (host NumPy, once per mesh), and the map
        from each raw entry (the terms' blocks in order) to its unique slot.  Contact
        changes never change the pattern."""
        n = self.layout.n_dofs
        host = jax.tree_util.tree_map(np.asarray, idx)
        parts = [_blocks_pattern(np.asarray(t.dofs(host), np.int64)) for t in self.terms]
        keys = np.concatenate([r for r, _ in parts]) * n + np.concatenate([c for _, c in parts])
        uniq, slot = np.unique(keys, return_inverse=True)
        idx = replace(idx, rows=_device_int32(uniq // n), cols=_device_int32(uniq % n),
                      slot=_device_int32(slot.ravel()))  # fmt: skip
        return replace(self, layout=replace(self.layout, n_nonzeros=len(uniq))), idx

    def nodal_positions(self, x, coords, idx: Indices):
        return coords + self.layout.nodal(x)[:, :2]

    def facet_ends(self, x, coords, idx: Indices):
        """(n_fc, 2, 2) current positions of the corner-contact facets' nodes a, b."""
        nodes = idx.facet_dofs[:, ::2] // self.layout.n_fields
        return self.nodal_positions(x, coords, idx)[nodes]

    def heat_flows(self, x, ctx: StepContext, gnew: GaussState):
        """(4,) the heat of a converged step (mJ): stored, generated by plastic work, given
        to the dies, given to the air (zeros without a temperature field)."""
        return self.element.heat_flows(x, ctx, gnew, self.layout)

    def contact_report(self, x, ctx: StepContext):
        """Per candidate at a converged x: (status 0/1/2, normal, tangent, slip increment)."""
        if self.layout.n_contact == 0:
            z = jnp.zeros((0, 2), dtype=x.dtype)
            return jnp.zeros(0, jnp.int32), z, z, jnp.zeros(0, dtype=x.dtype)
        return NodeContact(self.contact, self.layout).report(x, ctx)

    # -- global ---------------------------------------------------------------------
    def residual(self, x, ctx: StepContext):
        """Global residual; returns (R, new Gauss state, status code, force scale)."""
        ep = self.element.residual_pass(x, ctx, self.layout)
        return self._finish_residual(x, ep, ctx)

    def residual_and_jacobian(self, x, ctx: StepContext):
        """(R, Jacobian values on the pattern, new Gauss state, status code, force scale).
        A dead load ctx.f_ext adds nothing to the Jacobian."""
        ep = self.element.residual_pass(x, ctx, self.layout)
        r, gnew, ok, scale = self._finish_residual(x, ep, ctx)
        return r, self._pass_jacobian(x, ep, ctx), gnew, ok, scale

    def jacobian(self, x, ctx: StepContext, gauss: GaussState):
        """Jacobian values on the pattern at x, given ``gauss``, the new Gauss state of
        :meth:`residual` at the same x: the element Jacobians start from its local
        solutions, and no residual pass is repeated (a Newton iteration holds the
        residual of its iterate already)."""
        return self._pass_jacobian(x, self._pass_at(x, ctx, gauss), ctx)

    def _pass_at(self, x, ctx: StepContext, gauss: GaussState) -> ElementPass:
        """What a Jacobian pass reads of the element pass at x whose new Gauss state is
        ``gauss`` (the dofs, the element data and that state), without the pass."""
        edofs = ctx.idx.edofs
        return ElementPass(x[edofs], self.element.element_data(ctx), None, gauss, None, None)

    def _pass_jacobian(self, x, ep: ElementPass, ctx: StepContext):
        """Jacobian values on the pattern from an element pass at x (its dofs, element
        data and new Gauss state)."""
        element = self.element
        k_e, _ = element.jacobians(element.element_fn(ctx, self.layout), ep, ctx.gauss)
        return self._jacobian_values(x, ep._replace(k_e=k_e), ctx)

    def jacobian_and_state_vjp(self, x, ctx: StepContext, gauss: GaussState,
                               g_bar: GaussState):  # fmt: skip
        """(Jacobian values on the pattern, (dG/dx)^T g_bar) at x, G the new Gauss state
        (``gauss`` its value at x: no residual pass is repeated).

        For the reverse pass of a converged step: the forward-mode pass over the element
        dofs that gives the element Jacobians carries the derivative of each element's
        new Gauss state in the same tangents; contracting it with the cotangent g_bar
        right away costs a few small products instead of a reverse pass through the
        local material solves."""
        element = self.element
        fn = element.element_fn(ctx, self.layout)

        def fn_state(dofs_flat, elem, gs, solution):
            r, (_, gnew, code, _) = fn(dofs_flat, elem, gs, solution)
            return (r, gnew), code

        ep = self._pass_at(x, ctx, gauss)
        (k_e, dg_e), _ = element.jacobians(fn_state, ep, ctx.gauss)
        n_e, n_d = k_e.shape[0], k_e.shape[-1]
        xg_e = sum(
            jnp.einsum("ek,ekd->ed", gb.reshape(n_e, -1), dg.reshape(n_e, -1, n_d))
            for gb, dg in zip(jax.tree_util.tree_leaves(g_bar), jax.tree_util.tree_leaves(dg_e))
        )
        xg = jnp.zeros(self.layout.n_dofs, dtype=x.dtype).at[ctx.idx.edofs].add(xg_e)
        return self._jacobian_values(x, ep._replace(k_e=k_e), ctx), xg

    def _jacobian_values(self, x, ep: ElementPass, ctx: StepContext):
        """Every term's blocks summed into the pattern, then each term's conditions on
        its rows (Dirichlet rows identity)."""
        idx, n = ctx.idx, self.layout.n_dofs
        raw = jnp.concatenate([t.jacobian(x, ctx, ep).ravel() for t in self.terms])
        vals = jax.ops.segment_sum(raw, idx.slot, num_segments=self.layout.n_nonzeros)
        for t in self.terms:
            vals = t.constrain(vals, idx, n)
        return vals

    def _finish_residual(self, x, ep: ElementPass, ctx: StepContext):
        """(R, new Gauss state, status code, force scale): every term's part of R in
        order; the scale the largest of the terms' and the multipliers' norm."""
        r = jnp.zeros(self.layout.n_dofs, dtype=x.dtype)
        for t in self.terms:
            r = t.add_residual(r, x, ctx, ep)
        lam = jnp.concatenate([t.multipliers(x, ctx.idx) for t in self.terms])
        scale = jnp.linalg.norm(lam)
        for t in self.terms:
            scale = jnp.maximum(scale, t.scale(x, ctx, ep, self.layout))
        code = jnp.max(ep.code)
        code = jnp.where(jnp.all(jnp.isfinite(r)), code, NOT_FINITE)
        return r, ep.gauss, code, scale


@partial(jax.jit, static_argnums=0)
def internal_forces(model: Model, x, gstate, coords, dt, params, idx: Indices):
    """Assembled element force vector (no contact, no Dirichlet rows, isothermal): for
    reactions.  Compiled (one program, not an eager operation each, when called on the
    host)."""
    zero = jnp.zeros((), dtype=x.dtype)
    ctx = StepContext(gauss=gstate, coords=coords, t=zero, dt=dt, params=params, die=None,
                      c_contact=zero, cstep=None, idx=idx)  # fmt: skip
    ep = model.element.residual_pass(x, ctx, model.layout)
    return jnp.zeros(model.layout.n_dofs, dtype=x.dtype).at[idx.edofs].add(ep.r_e)
