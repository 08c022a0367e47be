"""Contact conditions between workpiece nodes and a rigid die: normal and friction.

Each candidate node i carries two multipliers: lambda_n (normal force the die puts on
the node, N) and lambda_t (tangential force along the die tangent t, N).  The die pushes
the node with lambda_n n + lambda_t t, so the node's force residual gains
-(lambda_n n + lambda_t t).  Both conditions are nonsmooth equations C = 0 solved exactly
by the global (semismooth) Newton; c > 0 (N/mm, from G times the element size) changes
only the path of the iterations, never the converged answer, and is not a user penalty.

Normal (gap g >= 0, lambda_n >= 0, lambda_n g = 0):
    C_n = lambda_n - max(0, lambda_n - c g).
The node is *active* where lambda_n - c g > 0.

Tangential, with s the slip increment of the step (relative tangential displacement of
the node against the die, mm) and the trial z = lambda_t - c s:
    inactive node:            C_t = lambda_t                    (no contact, no friction)
    active, |z| <= b (stick): C_t = c s                         (no slip)
    active, |z| >  b (slip):  C_t = lambda_t - b z / |z|        (|lambda_t| = b, opposing slip)
with the friction bound b of the law of the die that holds the node (each
:class:`jaxform.dies.RigidDie` owns one; a :class:`jaxform.dies.DieSet` selects the law of
its nearest die, :func:`pick_law`), the radial return of thesis Sec. 5.4 in force form:
    :class:`Frictionless`  C_t = lambda_t everywhere (no tangential force);
    :class:`Coulomb`       b = mu max(0, lambda_n - c g)  (= mu lambda_n at convergence);
    :class:`Shear`         b = m (sigma_eq / sqrt 3) A    (constant friction factor; sigma_eq
                           the nodal flow stress and A the node's contact area, both taken
                           at the start of the step: lagged by one step), rising linearly
                           from 0 over trial pressures 0 .. SHEAR_RAMP sigma_eq (so that
                           C_t is continuous where a node comes into contact);
    :class:`Sticking`      an active node never slips (C_t = c s; no infinite bound enters
                           the arithmetic, so the reverse pass stays NaN-free).
A law's bound reads a :class:`FrictionSite` (the trial normal force, the lagged flow stress
and contact area, the temperature): a law that depends on the contact pressure or the
temperature is one new :class:`BoundedFriction` class with its own ``bound``.  Coefficients
are the law's fields (traced leaves: differentiable); the law's kind is its class.

Candidates whose tangential motion a Dirichlet condition fixes (nodes on the axis of an
axisymmetric section, where the die tangent is radial; nodes on the mid-plane against a
die surface that runs more up than across, a mandrel or a side die) get C_t = lambda_t:
the condition holds there already and a friction equation would make the system singular.

Status of a converged node: 0 open, 1 stick, 2 slip (:func:`pair_status`).

Candidates and dies (``pairing``, ``die.contact_pairs``).  :class:`NearestDie`: a
candidate is a node and faces the die of a set with the least gap.  :class:`EachDie`: a
candidate is a (node, die) pair, every contact node against every die, so a node pressed
into the corner of two dies carries both dies' forces; a pair whose node touches two dies
at the step start is held by their normals and has no friction for the step
(:meth:`EachDie.cornered`).

Convex die corners.  Node contact alone lets a convex arc of the die reach between two
contact nodes into the facet that joins them (by the arc's sagitta over the facet).  With
corner contact on (``die.corner_contact``), each free-surface facet also carries one
normal multiplier against the die's convex arcs (:func:`facet_terms`), frictionless.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np

OPEN, STICK, SLIP = 0, 1, 2

# the contact pressure, as a fraction of the flow stress, from which shear friction holds
# in full (:class:`Shear`; below it the bound rises linearly from 0 at p = 0)
SHEAR_RAMP = 0.05


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class ContactStep:
    """Per-step constants of the contact conditions (from the state at t_n)."""

    x_old: jax.Array  # (n_c, 2) positions of the candidate nodes at t_n (mm)
    t_old: jax.Array  # t_n (s)
    fixed: jax.Array  # (n_c, 2) bool: the candidate's u_r, u_z are prescribed (Dirichlet)
    # what a friction law may read at t_n (lagged), per candidate; zeros where no law of the
    # scene's dies reads it (:func:`jaxform.stepping.contact_step`)
    sigma_eq: jax.Array  # (n_c,) nodal flow stress (MPa)
    area: jax.Array  # (n_c,) contact area of the facets in contact (mm^2)
    temperature_K: jax.Array  # (n_c,) nodal temperature (K; NaN in an isothermal run)
    # (n_c,) int: the die of each candidate where candidates are (node, die) pairs
    # (:class:`EachDie`); zeros where each faces its nearest die (:class:`NearestDie`)
    die: jax.Array | None = None
    # (n_c,) bool: the candidate's node touched another die too at t_n (:meth:`EachDie.cornered`)
    cornered: jax.Array | None = None


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class FrictionSite:
    """What the contact conditions know at a candidate when a law bounds its tangential
    force: the trial normal force lambda_n - c g (N; > 0 where the node is active, the
    normal force at convergence), and at t_n the nodal flow stress sigma_eq (MPa), the
    node's contact area A (mm^2) and its temperature (K)."""

    trial_n: jax.Array
    sigma_eq: jax.Array
    area: jax.Array
    temperature_K: jax.Array

    @property
    def shear_base(self):
        """sigma_eq / sqrt(3) A (N): the shear flow force of the node's contact area."""
        return self.sigma_eq / jnp.sqrt(3.0) * self.area

    @property
    def pressure(self):
        """The trial contact pressure max(0, lambda_n - c g) / A (MPa; 0 where A = 0)."""
        safe = jnp.where(self.area > 0.0, self.area, 1.0)
        return jnp.where(self.area > 0.0, jnp.maximum(0.0, self.trial_n) / safe, 0.0)


class FrictionLaw:
    """A die-workpiece friction law: the tangential condition of an active candidate.

    Subclasses are frozen PyTrees whose fields are the law's coefficients (traced,
    differentiable); ``coefficient_range`` gives each coefficient's allowed interval (the
    design group's bounds).  ``uses_flow_stress`` / ``uses_temperature``: the step start
    must supply sigma_eq and A / the temperature (:class:`ContactStep`)."""

    coefficient_range: ClassVar[dict[str, tuple[float, float]]] = {}
    uses_flow_stress: ClassVar[bool] = False
    uses_temperature: ClassVar[bool] = False

    def tangential(self, p: dict, site: FrictionSite, c):
        """(C_t, whether a node in contact counts as sticking) from the candidate's parts
        ``p`` (:meth:`ContactLaw._parts`) and site."""
        raise NotImplementedError


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class Frictionless(FrictionLaw):
    """No tangential force: C_t = lambda_t; a node in contact slips."""

    def tangential(self, p, site, c):
        return p["lam_t"], jnp.asarray(False)


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class Sticking(FrictionLaw):
    """An active node never slips: C_t = c s (where no Dirichlet condition fixes the
    tangential motion), without an infinite bound in the arithmetic (NaN-free VJP)."""

    def tangential(self, p, site, c):
        c_t = jnp.where(p["active"], c * p["slip"], p["lam_t"])
        return jnp.where(p["frictionless"], p["lam_t"], c_t), jnp.asarray(True)


class BoundedFriction(FrictionLaw):
    """A law with a finite bound b on |lambda_t| (:meth:`bound`, N): stick where the trial
    |z| <= b (C_t = c s), else slip (C_t = lambda_t - b z / |z|)."""

    def bound(self, site: FrictionSite):
        raise NotImplementedError

    def tangential(self, p, site, c):
        bound = self.bound(site)
        stick = p["az"] <= bound
        safe = jnp.where(stick, 1.0, p["az"])
        slip_eq = p["lam_t"] - bound * p["z"] / safe
        c_t = jnp.where(p["active"], jnp.where(stick, c * p["slip"], slip_eq), p["lam_t"])
        # where a Dirichlet condition fixes the tangential motion, friction has nothing to act on
        c_t = jnp.where(p["frictionless"], p["lam_t"], c_t)
        return c_t, stick | p["frictionless"]  # a fixed node cannot slip


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class Coulomb(BoundedFriction):
    """b = mu max(0, lambda_n - c g) (mu: Coulomb coefficient, -)."""

    mu: jax.Array
    coefficient_range: ClassVar[dict[str, tuple[float, float]]] = {"mu": (0.0, 10.0)}

    def bound(self, site):
        return self.mu * jnp.maximum(0.0, site.trial_n)


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class Shear(BoundedFriction):
    """b = m sigma_eq / sqrt(3) A where the trial contact pressure p = (lambda_n - c g) / A
    reaches SHEAR_RAMP sigma_eq, and m sigma_eq / sqrt(3) A p / (SHEAR_RAMP sigma_eq) below
    it (0 at p = 0); sigma_eq and A lagged by one step (m: shear friction factor, -).

    The ramp makes C_t continuous where a node comes into contact: with the full bound
    from the first positive trial force, C_t jumped from lambda_t (inactive) to
    lambda_t - b z / |z| or c s (active) as lambda_n - c g crossed 0, and Newton stalled
    at a node sitting on that switch (its line search finds no decrease either side:
    docs/theory.md, "Shear friction where contact begins")."""

    m: jax.Array
    coefficient_range: ClassVar[dict[str, tuple[float, float]]] = {"m": (0.0, 1.0)}
    uses_flow_stress: ClassVar[bool] = True

    def bound(self, site):
        pressed = jnp.maximum(0.0, site.trial_n) / (jnp.sqrt(3.0) * SHEAR_RAMP)
        return self.m * jnp.minimum(site.shear_base, pressed)


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class FrictionChoice(FrictionLaw):
    """The law of die ``which`` among the different laws of a die set: each law's
    condition evaluated, the chosen one's taken."""

    laws: tuple
    which: jax.Array

    def tangential(self, p, site, c):
        parts = [law.tangential(p, site, c) for law in self.laws]
        c_t = jnp.stack([q[0] for q in parts])[self.which]
        sticks = jnp.stack([jnp.broadcast_to(q[1], ()) for q in parts])[self.which]
        return c_t, sticks


def pick_law(laws, which):
    """The friction law of die ``which`` (traced index) of ``laws`` (one per die): laws of
    one class give one law with the chosen die's coefficients; laws of different classes a
    :class:`FrictionChoice`."""
    laws = tuple(laws)
    if len(laws) == 1:
        return laws[0]
    if len({jax.tree_util.tree_structure(law) for law in laws}) == 1:
        return jax.tree_util.tree_map(lambda *v: jnp.stack(v)[which], *laws)
    return FrictionChoice(laws, which)


def flatten_laws(laws):
    """The distinct law classes under ``laws`` (opening a :class:`FrictionChoice`)."""
    out = []
    for law in laws:
        out.extend(flatten_laws(law.laws) if isinstance(law, FrictionChoice) else [law])
    return out


@dataclass(frozen=True)
class NearestDie:
    """Strategy: a candidate is a workpiece node, and it faces the die with the least gap
    (:meth:`jaxform.dies.DieSet.frame`): one multiplier pair per node.  A node pressed into
    the corner of two dies can carry only one of their forces."""

    def copies(self, n_dies: int) -> int:
        """How many candidates each contact node gives: one."""
        return 1

    def frame(self, die, x, t, t_old, which):
        return die.frame(x, t, t_old)

    def ghost_die(self, die):
        """The die a padding's ghost candidates face (:mod:`jaxform.capacity`): all."""
        return die

    def cornered(self, die, pos, idx, t, n_nodes: int):
        """None: a node faces one die, never two at once."""
        return None


@dataclass(frozen=True)
class EachDie:
    """Strategy: a candidate is a (node, die) pair, every contact node against every die
    of the set (:meth:`jaxform.dies.DieSet.member_frame`): one multiplier pair per node and
    die, each with that die's friction law, so a node pressed into the corner of two dies
    (a container wall and the punch or the bottom die) carries both dies' forces.  With
    one die it is :class:`NearestDie`."""

    def copies(self, n_dies: int) -> int:
        """How many candidates each contact node gives: one per die."""
        return n_dies

    def frame(self, die, x, t, t_old, which):
        return die.member_frame(x, t, t_old, which)

    def ghost_die(self, die):
        """The die a padding's ghost candidates face: the first (they are its pairs), so
        they need room away from it only (inside a closed container there is none away
        from every die)."""
        return die.members[0]

    def cornered(self, die, pos, idx, t, n_nodes: int):
        """(n_c,) bool: the candidate's node (of ``n_nodes``; candidate positions ``pos``)
        touches its die and another one at time t (gap
        <= TOUCH_GAP_MM to both): held in the corner by the two dies' normals, which fix
        both its displacement components, so its tangential conditions are frictionless
        for the step (two friction conditions on top, sticking, would repeat the normal
        ones: a singular system).  Lagged like the shear law's area: a node that leaves
        one of the dies during the step slides on the other without friction for that
        step."""
        f = candidate_frames(self, die, pos, idx.contact_die, t, t)
        touching = f.g <= TOUCH_GAP_MM
        per_node = (
            jnp.zeros(n_nodes, jnp.int32).at[idx.contact_nodes].add(touching.astype(jnp.int32))
        )
        return touching & (per_node[idx.contact_nodes] >= 2)


def candidate_frames(pairing, die, pos, which, t, t_old):
    """The :class:`jaxform.dies.DieFrame` of every candidate (vmapped) at positions pos
    (n_c, 2), of die ``which`` (n_c,) where the candidates are pairs (``pairing``)."""
    return jax.vmap(lambda p, k: pairing.frame(die, p, t, t_old, k))(pos, which)


@dataclass(frozen=True)
class ContactLaw:
    """Strategy: the node-to-die contact conditions; the friction law of each die lives in
    the die pytree (a :class:`jaxform.dies.RigidDie`, or a :class:`jaxform.dies.DieSet`
    whose nearest die holds the node, or each die its own candidate: ``pairing``)."""

    pairing: NearestDie | EachDie = NearestDie()
    # a corner-contact facet also open until an arc reaches past its nodes' own depth in
    # the die (facet_terms): the law of a step retried after a singular Jacobian
    facets_by_node_depth: bool = False

    def frames(self, die, pos, which, t, t_old):
        """Every candidate's die frame (:func:`candidate_frames`)."""
        return candidate_frames(self.pairing, die, pos, which, t, t_old)

    def _parts(self, die, x, lam, t, c, step: ContactStep, k):
        """The quantities both the residual and the status read for candidate k, and the
        friction law of the die that holds it."""
        # the surface, motion and friction of the nearest die or of the candidate's die
        which = None if step.die is None else step.die[k]
        f = self.pairing.frame(die, x, t, step.t_old, which)
        g, n, tan = f.g, f.n, f.tan
        slip = jnp.dot(x - step.x_old[k] - f.move, tan)
        lam_n, lam_t = lam[0], lam[1]
        trial_n = lam_n - c * g
        active = trial_n > 0.0
        z = lam_t - c * slip
        az = jnp.abs(z)
        # the tangential motion is prescribed: u_r held (a node on the axis), or u_z held
        # (on the mid-plane) against a die surface that runs more up than across (a mandrel)
        fixed = step.fixed[k]
        frictionless = fixed[0] | (fixed[1] & (jnp.abs(tan[1]) > jnp.abs(tan[0])))
        if step.cornered is not None:  # held in the corner of two dies (EachDie.cornered)
            frictionless = frictionless | step.cornered[k]
        site = FrictionSite(trial_n=trial_n, sigma_eq=step.sigma_eq[k], area=step.area[k],
                            temperature_K=step.temperature_K[k])  # fmt: skip
        p = dict(g=g, n=n, tan=tan, slip=slip, lam_n=lam_n, lam_t=lam_t, trial_n=trial_n,
                 active=active, z=z, az=az, frictionless=frictionless)  # fmt: skip
        return p, f.friction, site

    def pair_terms(self, die, x, lam, t, c, step: ContactStep, k):
        """Candidate k at position x with multipliers lam = (lambda_n, lambda_t):
        (force residual on the node (2,), complementarity residuals (2,))."""
        p, law, site = self._parts(die, x, lam, t, c, step, k)
        r_u = -(p["lam_n"] * p["n"] + p["lam_t"] * p["tan"])
        c_n = p["lam_n"] - jnp.maximum(0.0, p["trial_n"])
        c_t, _ = law.tangential(p, site, c)
        return r_u, jnp.stack([c_n, c_t])

    def pair_status(self, die, x, lam, t, c, step: ContactStep, k):
        """(status OPEN/STICK/SLIP, normal n, tangent t, slip increment) at convergence."""
        p, law, site = self._parts(die, x, lam, t, c, step, k)
        in_contact = p["lam_n"] > 0.0
        _, sticks = law.tangential(p, site, c)
        status = jnp.where(in_contact, jnp.where(sticks, STICK, SLIP), OPEN)
        return status, p["n"], p["tan"], p["slip"]


# A corner-contact facet with no force counts as open until a die's arc reaches this far
# into it (mm). Without it a facet lying on a flat face where an arc ends tangent to it
# (gap 0 to round-off, multiplier 0: a new mesh's carried state) is active by round-off,
# and its condition ties with its nodes' own: a singular Jacobian. 1e-9 mm is far above
# the round-off of a gap (~1e-15 mm) and far below any motion the solver resolves.
FACET_OPEN_REACH_MM = 1e-9


def facet_terms(die, v, t, c, by_node_depth: bool = False):
    """Corner contact of one workpiece facet, v = (x_a (2), x_b (2), mu): (force residual
    on its two nodes (4,), complementarity residual (1,)).

    The facet's gap to the die's convex arcs g(x_a, x_b) (:meth:`RigidDie.facet_gap`)
    with a normal multiplier mu >= 0 (N, frictionless): C = mu - max(0, mu - c (g + e)),
    e = :data:`FACET_OPEN_REACH_MM`, and the nodes' residuals gain -mu dg/dx (the die
    pushes the facet back along the arc's normal, shared between the nodes by where the
    arc touches).

    ``by_node_depth``: e also holds the deeper node's depth in the die (0 where neither
    is inside).  Where a Newton iterate has both nodes inside a flat face and an arc
    ending tangent to that face between them, the arc reaches into the facet exactly as
    far as the nodes' depths interpolate, and the active condition is a combination of the
    nodes' own: a singular Jacobian.  With it the facet stays open there; at a converged
    state, where a node in contact has g = 0, the law is the same.  It moves the Newton
    path wherever nodes start a step inside the die (more iterations on the closed dies),
    so it is the law of a step retried after a singular Jacobian
    (:func:`jaxform.chunks.chunk`), not of every step."""
    mu = v[4]

    def gap(xs):
        return die.facet_gap(xs[:2], xs[2:], t)[0]

    g, dg = jax.value_and_grad(gap)(v[:4])
    reach = FACET_OPEN_REACH_MM
    if by_node_depth:
        g_a, g_b = die.gap(v[:2], t)[0], die.gap(v[2:4], t)[0]
        g_in = jnp.where(g_a < g_b, g_a, g_b)
        reach = reach + jnp.where(g_in < 0.0, -g_in, 0.0)  # where: no derivative at 0
    c_n = mu - jnp.maximum(0.0, mu - c * (g + reach))
    return jnp.concatenate([-mu * dg, c_n[None]])


def facet_normal(xa, xb):
    """Unit normal of the facet xa -> xb out of the material (on its right)."""
    d = xb - xa
    return jnp.stack([d[..., 1], -d[..., 0]], axis=-1) / jnp.linalg.norm(d, axis=-1, keepdims=True)


def nodal_average(values_el, elements, n_nodes: int):
    """Average of element values (n_el,) over the elements around each node."""
    total = jnp.zeros(n_nodes, values_el.dtype).at[elements].add(values_el[:, None])
    count = jnp.zeros(n_nodes, values_el.dtype).at[elements].add(1.0)
    return total / jnp.maximum(count, 1.0)


TOUCH_GAP_MM = 1e-3  # a candidate this close to the die at the step start counts as touching


def facets_in_contact(touching, facets):
    """(n_f,) 1.0 for the candidate facets whose two nodes are touching (a (n_c,) bool
    mask: gap <= TOUCH_GAP_MM at a step's start, or the converged contact status), else
    0.0: the facets whose area carries the contact tractions (``counted`` of
    :func:`jaxform.geometry.tributary_areas`)."""
    return (touching[facets[:, 0]] & touching[facets[:, 1]]).astype(float)


@dataclass(frozen=True)
class Candidates:
    """The contact candidates of a mesh (host NumPy): ``nodes`` (n_c,) their nodes,
    ``die`` (n_c,) the die each candidate faces where candidates are (node, die) pairs
    (:class:`jaxform.contact.EachDie`; zeros: the nearest die), ``facets`` (n_f, 2) node
    pairs of the free surface (for contact areas; the corner-contact facets, with their
    own multiplier, are those of die 0) and ``facet_die`` (n_f,) the die of each facet's
    candidates.  A node appears once per die it is paired with."""

    nodes: np.ndarray
    facets: np.ndarray
    die: np.ndarray | None = None
    facet_die: np.ndarray | None = None

    @classmethod
    def paired(cls, nodes, facets, copies: int = 1) -> Candidates:
        """Every node and facet once per die (``copies`` dies), die after die."""
        nodes = np.asarray(nodes, dtype=np.int64)
        facets = np.asarray(facets, dtype=np.int64).reshape(-1, 2)
        return cls(
            nodes=np.tile(nodes, copies),
            facets=np.tile(facets, (copies, 1)),
            die=np.repeat(np.arange(copies), len(nodes)),
            facet_die=np.repeat(np.arange(copies), len(facets)),
        )

    def dies(self) -> tuple[np.ndarray, np.ndarray]:
        """(die of each candidate, die of each facet), zeros where not given."""
        die = np.zeros(len(self.nodes), np.int64) if self.die is None else self.die
        fdie = np.zeros(len(self.facets), np.int64) if self.facet_die is None else self.facet_die
        return np.asarray(die, np.int64), np.asarray(fdie, np.int64)
