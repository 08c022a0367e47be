"""Degrees of freedom, the fixed sparsity pattern, and global residual/Jacobian assembly.

Unknown vector x = [nodal fields (n_nodes * n_fields) | contact multipliers (2 n_contact)
| corner multipliers (n_facets)], node a's field k at a * n_fields + k (fields: u_r, u_z[,
p]); candidate i's normal and tangential multipliers at n_nodes * n_fields + 2 i + (0, 1);
facet f's corner-contact multiplier (:func:`jaxform.contact.facet_terms`) after those.

Set-up (NumPy, once per scene) builds :class:`Indices`: element dof maps, Dirichlet dofs,
contact candidates, and the *unique* sparsity pattern holding every entry any element
or any contact candidate can ever produce, with the map from each raw entry to its
unique slot.  Contact changes never change the pattern.

In jit: element residuals are vmapped over elements; their Jacobians come from
``jax.jacfwd`` of the same function (no hand-derived tangent), and are summed into the
pattern with one segment_sum.  Dirichlet rows become identity rows.

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

from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from jaxform import element as el
from jaxform.contact import ContactLaw, ContactStep, facet_terms
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
        start = self.n_node_dofs
        return x[start : start + 2 * self.n_contact].reshape(self.n_contact, 2)

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
        NumPy arrays).  The one place that knows the layout of x's nodal part."""
        return x[: self.n_node_dofs].reshape(self.n_nodes, self.n_fields)


def _device_int32(a) -> jax.Array:
    """An index array on the device as int32, converted on the host and put there by
    ``jax.device_put`` (``jnp.asarray`` of a host array compiles, or loads, a small copy
    program per shape and dtype; so does a conversion on the device)."""
    return jax.device_put(np.asarray(a, dtype=np.int32))


def build_indices(
    mesh,
    n_fields: int,
    fixed_dofs: np.ndarray,
    contact_nodes: np.ndarray,
    reaction_dofs: np.ndarray | None = None,
    contact_facets: np.ndarray | None = None,
    load_facets: np.ndarray | None = None,
    corner_contact: bool = False,
) -> tuple[Layout, Indices]:
    """contact_facets: (n_f, 2) node pairs of the free surface (for contact areas; with
    ``corner_contact`` each also gets a corner-contact multiplier); load_facets: (n_lf, 2)
    node pairs of the boundary carrying a traction load."""
    nf = n_fields
    n_nodes = mesh.n_nodes
    elements = np.asarray(mesh.elements, dtype=np.int64)
    edofs = (elements[:, :, None] * nf + np.arange(nf)[None, None, :]).reshape(len(elements), -1)
    n_c = len(contact_nodes)
    ndof_nodes = n_nodes * nf
    cdofs = contact_nodes[:, None] * nf + np.arange(2)[None, :]
    mdofs = ndof_nodes + np.arange(2 * n_c).reshape(n_c, 2)
    walked = _oriented(elements, contact_facets)
    corner = walked if corner_contact else np.zeros((0, 2), int)
    n_fc = len(corner)
    n = ndof_nodes + 2 * n_c + n_fc
    fdofs = (corner[:, :, None] * nf + np.arange(2)[None, None, :]).reshape(n_fc, 4)
    fmult = ndof_nodes + 2 * n_c + np.arange(n_fc)
    # raw entries: element blocks, contact 3x3 blocks (u_r, u_z, lambda), diagonal
    er = np.repeat(edofs[:, :, None], edofs.shape[1], axis=2).ravel()
    ec = np.repeat(edofs[:, None, :], edofs.shape[1], axis=1).ravel()
    cblock = np.column_stack([cdofs, mdofs])  # (n_c, 4): u_r, u_z, lambda_n, lambda_t
    cr = np.repeat(cblock[:, :, None], 4, axis=2).ravel()
    cc = np.repeat(cblock[:, None, :], 4, axis=1).ravel()
    fblock = np.column_stack([fdofs, fmult])  # (n_fc, 5): u of a, u of b, mu
    fr = np.repeat(fblock[:, :, None], 5, axis=2).ravel()
    fc = np.repeat(fblock[:, None, :], 5, axis=1).ravel()
    dr = np.arange(n)
    raw_r = np.concatenate([er, cr, fr, dr])
    raw_c = np.concatenate([ec, cc, fc, dr])
    keys = raw_r * n + raw_c
    uniq, slot = np.unique(keys, return_inverse=True)
    layout = Layout(n_nodes, nf, n_c, len(elements), len(uniq), n_fc)
    idx = Indices(
        edofs=_device_int32(edofs),
        elements=_device_int32(elements),
        fixed=_device_int32(np.asarray(fixed_dofs, dtype=np.int64)),
        contact_nodes=_device_int32(contact_nodes),
        contact_dofs=_device_int32(cdofs),
        mult_dofs=_device_int32(mdofs),
        contact_facets=_device_int32(_local_facets(contact_nodes, walked)),
        contact_fixed=jax.device_put(np.isin(cdofs[:, :2], np.asarray(fixed_dofs))),
        facet_dofs=_device_int32(fdofs),
        facet_mult=_device_int32(fmult),
        rows=_device_int32(uniq // n),
        cols=_device_int32(uniq % n),
        slot=_device_int32(slot.ravel()),
        bottom_reaction_dofs=_device_int32(
            reaction_dofs if reaction_dofs is not None else np.zeros(0, np.int64)
        ),
        load_facets=_device_int32(
            np.zeros((0, 2), np.int64)
            if load_facets is None
            else np.asarray(load_facets, dtype=np.int64)
        ),
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


def _local_facets(contact_nodes, facets) -> np.ndarray:
    if facets is None or len(facets) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    local = -np.ones(int(max(contact_nodes.max(), np.max(facets))) + 1, dtype=np.int64)
    local[contact_nodes] = np.arange(len(contact_nodes))
    out = local[np.asarray(facets, dtype=np.int64)]
    if np.any(out < 0):
        raise ValueError("contact facets must join contact candidate nodes")
    return out


@dataclass(frozen=True)
class Model:
    """What the assembly needs besides arrays: formulation, law, contact law, sizes (static)."""

    formulation: Formulation
    law: object
    layout: Layout
    contact: ContactLaw = ContactLaw()
    jacobian_chunk: int = 512  # elements per chunk of the element Jacobians; 0: one vmap

    # -- element level --------------------------------------------------------------
    def _element_fn(self, ctx: StepContext):
        """The element function of the step: (dofs, (x_ref, heat), Gauss state[,
        solution]) -> (r_e, aux), aux = (r_e, new Gauss state, code, heat scale (4,))."""
        form, law, lay = self.formulation, self.law, self.layout
        params, dt, th = ctx.params, ctx.dt, ctx.thermal

        def fn(dofs_flat, elem, gstate, solution=None):
            x_ref, heat = elem
            dofs = dofs_flat.reshape(4, lay.n_fields)
            if th is None:
                given = PointGiven(solution)
                r, gnew, code = form.residual(law, params, dt, x_ref, dofs, gstate, given)
                return r.ravel(), (r.ravel(), gnew, code, jnp.zeros(4, dofs.dtype))
            theta = dofs[:, -1]  # the change from the billet temperature (K)
            temp = th.billet_temperature_K + theta
            given = PointGiven(solution, el.N_GP @ temp)
            r, gnew, code = form.residual(law, params, dt, x_ref, dofs[:, :-1], gstate, given)
            work = plastic_work(gstate.mat, gnew.mat)
            terms = element_heat(th, dt, x_ref, dofs[:, :2], theta, heat, work, form.axisymmetric)
            # thermal rows: the heat of the step (mJ = N mm), like forces in N for mm parts
            r = jnp.concatenate([r, dt * terms.residual()[:, None]], axis=1)
            code = jnp.maximum(code, jnp.where(jnp.all(temp > 0.0), 0, NO_TEMPERATURE))
            return r.ravel(), (r.ravel(), gnew, code, dt * terms.magnitude())

        return fn

    def _element_data(self, ctx: StepContext):
        """What each element's function reads besides its dofs and Gauss state."""
        return ctx.coords[ctx.idx.elements], ctx.heat

    def _element_residuals(self, fn, x, ctx: StepContext):
        """The residual pass: (dofs, element data, r_e, new Gauss state, codes, heat
        scales) of every element, one vmap (the material's local solves run vectorized
        over the whole mesh)."""
        xe, elem = self._gather(x, ctx.idx), self._element_data(ctx)
        r_e, (_, gnew, ok_e, heat_e) = jax.vmap(fn)(xe, elem, ctx.gauss)
        return xe, elem, r_e, gnew, ok_e, heat_e

    def _element_jacobians(self, fn, xe, elem, gstate, solution: GaussState):
        """vmap(jacfwd(fn, has_aux=True)) over the elements, in chunks of
        ``jacobian_chunk`` (see the module docstring), at the new Gauss state
        ``solution`` of the residual pass (no local solve is repeated); returns what the
        plain vmap returns (for the element function: (k_e, aux))."""
        jac = jax.vmap(jax.jacfwd(fn, has_aux=True))
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

    def heat_flows(self, x, ctx: StepContext, gnew: GaussState):
        """(4,) the heat of a converged step (mJ): stored, generated by plastic work, given
        to the dies, given to the air; stored = plastic - dies - air at convergence."""
        if ctx.thermal is None:
            return jnp.zeros(4, dtype=x.dtype)
        lay, form = self.layout, self.formulation
        nodal = lay.nodal(x)[ctx.idx.elements]  # (n_el, 4, n_fields)
        x_ref, heat = self._element_data(ctx)

        def one(x_e, u, theta, h, old, new):
            work = plastic_work(old, new)
            terms = element_heat(ctx.thermal, ctx.dt, x_e, u, theta, h, work, form.axisymmetric)
            return jnp.stack([jnp.sum(terms.stored), jnp.sum(terms.plastic),
                              jnp.sum(terms.die), jnp.sum(terms.air)])  # fmt: skip

        per_el = jax.vmap(one)(x_ref, nodal[..., :2], nodal[..., -1], heat, ctx.gauss.mat, gnew.mat)
        return ctx.dt * per_el.sum(axis=0)

    def _gather(self, x, idx: Indices):
        return x[idx.edofs]

    def nodal_positions(self, x, coords, idx: Indices):
        return coords + self.layout.nodal(x)[:, :2]

    # -- global ---------------------------------------------------------------------
    def residual(self, x, ctx: StepContext):
        """Global residual; returns (R, new Gauss state, status code, force scale)."""
        fn = self._element_fn(ctx)
        _, _, r_e, gnew, ok_e, heat_e = self._element_residuals(fn, x, ctx)
        return self._finish_residual(x, r_e, gnew, ok_e, heat_e, ctx)

    def _contact_fn(self, ctx: StepContext):
        def fn(v, k):  # v = (x_r, x_z, lambda_n, lambda_t) of candidate k
            r_u, comp = self.contact.pair_terms(
                ctx.die, v[:2], v[2:], ctx.t, ctx.c_contact, ctx.cstep, k
            )
            return jnp.concatenate([r_u, comp])

        return fn

    def _contact_vars(self, x, coords, idx):
        pos = self.nodal_positions(x, coords, idx)[idx.contact_nodes]
        return jnp.concatenate([pos, x[idx.mult_dofs]], axis=1)

    def facet_ends(self, x, coords, idx: Indices):
        """(n_fc, 2, 2) current positions of the corner-contact facets' nodes a, b."""
        nodes = idx.facet_dofs[:, ::2] // self.layout.n_fields
        return self.nodal_positions(x, coords, idx)[nodes]

    def _facet_terms(self, x, ctx: StepContext, derivative: bool):
        """Corner contact of every facet (:func:`jaxform.contact.facet_terms`): its (n_fc,
        5) residual entries, or with ``derivative`` their (n_fc, 5, 5) Jacobian blocks."""
        idx = ctx.idx
        pos = self.facet_ends(x, ctx.coords, idx).reshape(-1, 4)
        v = jnp.concatenate([pos, x[idx.facet_mult][:, None]], axis=1)

        def fn(vf):
            return facet_terms(ctx.die, vf, ctx.t, ctx.c_contact)

        return jax.vmap(jax.jacfwd(fn) if derivative else fn)(v)

    def contact_report(self, x, ctx: StepContext):
        """Per candidate at a converged x: (status 0/1/2, normal, tangent, slip increment)."""
        if self.layout.n_contact == 0:
            z = jnp.zeros((0, 2), dtype=x.dtype)
            return jnp.zeros(0, jnp.int32), z, z, jnp.zeros(0, dtype=x.dtype)
        v = self._contact_vars(x, ctx.coords, ctx.idx)
        return jax.vmap(
            lambda vk, k: self.contact.pair_status(
                ctx.die, vk[:2], vk[2:], ctx.t, ctx.c_contact, ctx.cstep, k
            )
        )(v, jnp.arange(self.layout.n_contact))

    def residual_and_jacobian(self, x, ctx: StepContext):
        """(R, Jacobian values on the pattern, new Gauss state, status code, force scale).
        A dead load ctx.f_ext adds nothing to the Jacobian."""
        fn = self._element_fn(ctx)
        xe, elem, r_e, gnew, ok_e, heat_e = self._element_residuals(fn, x, ctx)
        k_e, _ = self._element_jacobians(fn, xe, elem, ctx.gauss, gnew)
        r, gnew, ok, scale = self._finish_residual(x, r_e, gnew, ok_e, heat_e, ctx)
        return r, self._jacobian_values(x, k_e, ctx), gnew, ok, scale

    def jacobian_and_state_vjp(self, x, ctx: StepContext, g_bar: GaussState):
        """(Jacobian values on the pattern, (dG/dx)^T g_bar) at x, G the new Gauss state.

        For the reverse pass of a converged step: the forward-mode pass over the element
        dofs that gives the element Jacobians carries the derivative of each element's
        new Gauss state in the same tangents; contracting it with the cotangent g_bar
        right away costs a few small products instead of a reverse pass through the
        local material solves."""
        fn = self._element_fn(ctx)

        def fn_state(dofs_flat, elem, gs, solution):
            r, (_, gnew, code, _) = fn(dofs_flat, elem, gs, solution)
            return (r, gnew), code

        xe, elem, _, g_conv, _, _ = self._element_residuals(fn, x, ctx)
        (k_e, dg_e), _ = self._element_jacobians(fn_state, xe, elem, ctx.gauss, g_conv)
        n_e, n_d = k_e.shape[0], k_e.shape[-1]
        xg_e = sum(
            jnp.einsum("ek,ekd->ed", gb.reshape(n_e, -1), dg.reshape(n_e, -1, n_d))
            for gb, dg in zip(jax.tree_util.tree_leaves(g_bar), jax.tree_util.tree_leaves(dg_e))
        )
        xg = jnp.zeros(self.layout.n_dofs, dtype=x.dtype).at[ctx.idx.edofs].add(xg_e)
        return self._jacobian_values(x, k_e, ctx), xg

    def _jacobian_values(self, x, k_e, ctx: StepContext):
        """Element and contact blocks summed into the pattern; Dirichlet rows identity."""
        idx = ctx.idx
        # contact blocks (4 x 4 per candidate)
        if self.layout.n_contact:
            k_c = jax.vmap(jax.jacfwd(self._contact_fn(ctx)))(
                self._contact_vars(x, ctx.coords, idx), jnp.arange(self.layout.n_contact)
            )
        else:
            k_c = jnp.zeros((0, 4, 4), dtype=x.dtype)
        k_f = self._facet_terms(x, ctx, True) if self.layout.n_facets else jnp.zeros(0, x.dtype)
        n = self.layout.n_dofs
        raw = jnp.concatenate([k_e.ravel(), k_c.ravel(), k_f.ravel(), jnp.zeros(n, x.dtype)])
        vals = jax.ops.segment_sum(raw, idx.slot, num_segments=self.layout.n_nonzeros)
        # Dirichlet rows -> identity rows
        fixed_row = jnp.zeros(n, dtype=bool).at[idx.fixed].set(True)
        is_fixed = fixed_row[idx.rows]
        return jnp.where(is_fixed, jnp.where(idx.rows == idx.cols, 1.0, 0.0), vals)

    def _finish_residual(self, x, r_e, gnew, ok_e, heat_e, ctx: StepContext):
        idx, f_ext = ctx.idx, ctx.f_ext
        n = self.layout.n_dofs
        r = jnp.zeros(n, dtype=x.dtype).at[idx.edofs].add(r_e)
        lam = x[idx.mult_dofs]
        if self.layout.n_contact:
            rc = jax.vmap(self._contact_fn(ctx))(
                self._contact_vars(x, ctx.coords, idx), jnp.arange(self.layout.n_contact)
            )
            r = r.at[idx.contact_dofs].add(rc[:, :2])
            r = r.at[idx.mult_dofs].set(rc[:, 2:])
        if self.layout.n_facets:
            rf = self._facet_terms(x, ctx, False)
            r = r.at[idx.facet_dofs].add(rf[:, :4])
            r = r.at[idx.facet_mult].set(rf[:, 4])
            lam = jnp.concatenate([lam.ravel(), x[idx.facet_mult]])
        if f_ext is not None:
            r = r - f_ext
        r = r.at[idx.fixed].set(x[idx.fixed])
        nf = self.layout.n_fields
        r_u_e = r_e.reshape(r_e.shape[0], 4, nf)[:, :, :2]
        scale = jnp.maximum(jnp.sqrt(jnp.sum(r_u_e**2)), jnp.linalg.norm(lam))
        if f_ext is not None:
            scale = jnp.maximum(scale, jnp.linalg.norm(f_ext))
        if ctx.thermal is not None:  # the heat of the step (mJ): what the thermal rows carry
            scale = jnp.maximum(scale, jnp.sqrt(jnp.sum(heat_e**2)))
        code = jnp.max(ok_e)
        code = jnp.where(jnp.all(jnp.isfinite(r)), code, NOT_FINITE)
        return r, gnew, code, scale


@partial(jax.jit, static_argnums=0)
def internal_forces(model: Model, x, gstate, coords, dt, params, idx: Indices):
    """Assembled element force vector (no contact, no Dirichlet rows, isothermal): for
    reactions.  Compiled (one program, not an eager operation each, when called on the
    host)."""
    zero = jnp.zeros((), dtype=x.dtype)
    ctx = StepContext(gauss=gstate, coords=coords, t=zero, dt=dt, params=params, die=None,
                      c_contact=zero, cstep=None, idx=idx)  # fmt: skip
    _, _, r_e, _, _, _ = model._element_residuals(model._element_fn(ctx), x, ctx)
    return jnp.zeros(model.layout.n_dofs, dtype=x.dtype).at[idx.edofs].add(r_e)
