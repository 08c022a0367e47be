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
with the friction bound b of the law (the radial return of thesis Sec. 5.4 in force form):
    ``none``      b = 0 (C_t = lambda_t everywhere: frictionless);
    ``coulomb``   b = mu max(0, lambda_n - c g)  (= mu lambda_n at convergence);
    ``shear``     b = m (sigma_eq / sqrt 3) A    (constant friction factor; sigma_eq the
                  nodal flow stress and A the node's contact area, both taken at the start
                  of the step: lagged by one step, see :func:`shear_bounds`);
    ``sticking``  b = infinity (an active node never slips).

Candidates whose tangential motion a Dirichlet condition fixes (nodes on the axis of an
axisymmetric section, where the die tangent is radial; nodes on the mid-plane against a
die surface that runs more up than across, a mandrel or a side die) get C_t = lambda_t:
the condition holds there already and a friction equation would make the system singular.

Status of a converged node: 0 open, 1 stick, 2 slip (:func:`pair_status`).

Convex die corners.  Node contact alone lets a convex arc of the die reach between two
contact nodes into the facet that joins them (by the arc's sagitta over the facet).  With
corner contact on (``die.corner_contact``), each free-surface facet also carries one
normal multiplier against the die's convex arcs (:func:`facet_terms`), frictionless.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp

FRICTION_MODELS = ("none", "coulomb", "shear", "sticking")
OPEN, STICK, SLIP = 0, 1, 2


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class ContactStep:
    """Per-step constants of the contact conditions (from the state at t_n)."""

    x_old: jax.Array  # (n_c, 2) positions of the candidate nodes at t_n (mm)
    t_old: jax.Array  # t_n (s)
    shear_bound: jax.Array  # (n_c,) m sigma_eq/sqrt(3) A at t_n (N); 0 unless 'shear'
    fixed: jax.Array  # (n_c, 2) bool: the candidate's u_r, u_z are prescribed (Dirichlet)


@dataclass(frozen=True)
class ContactLaw:
    """Strategy: the friction model (static); coefficients live in the die pytree (a
    :class:`jaxform.dies.RigidDie`, or a :class:`jaxform.dies.DieSet` whose nearest die
    holds the node)."""

    friction: str = "none"

    def __post_init__(self):
        if self.friction not in FRICTION_MODELS:
            raise ValueError(
                f"friction.model = {self.friction!r}: must be one of {', '.join(FRICTION_MODELS)}"
            )

    def _parts(self, die, x, lam, t, c, step: ContactStep, k):
        """The quantities both the residual and the status read for candidate k."""
        friction = self.friction
        f = die.frame(x, t, step.t_old)  # the nearest die's surface, motion and friction
        g, n, tan = f.g, f.n, f.tan
        slip = jnp.dot(x - step.x_old[k] - f.move, tan)
        lam_n, lam_t = lam[0], lam[1]
        trial_n = lam_n - c * g
        active = trial_n > 0.0
        z = lam_t - c * slip
        if friction == "coulomb":
            bound = f.mu * jnp.maximum(0.0, trial_n)
        elif friction == "shear":
            bound = step.shear_bound[k]
        elif friction == "sticking":
            bound = jnp.asarray(jnp.inf)  # only compared, never multiplied
        else:
            bound = 0.0
        az = jnp.abs(z)
        stick = az <= bound
        # the tangential motion is prescribed: u_r held (a node on the axis), or u_z held
        # (on the mid-plane) against a die surface that runs more up than across (a mandrel)
        fixed = step.fixed[k]
        frictionless = fixed[0] | (fixed[1] & (jnp.abs(tan[1]) > jnp.abs(tan[0])))
        return dict(
            g=g,
            n=n,
            tan=tan,
            slip=slip,
            lam_n=lam_n,
            lam_t=lam_t,
            trial_n=trial_n,
            active=active,
            z=z,
            az=az,
            bound=bound,
            stick=stick,
            frictionless=frictionless,
        )

    def pair_terms(self, die, x, lam, t, c, step: ContactStep, k):
        """Candidate k at position x with multipliers lam = (lambda_n, lambda_t):
        (force residual on the node (2,), complementarity residuals (2,))."""
        p = self._parts(die, x, lam, t, c, step, k)
        r_u = -(p["lam_n"] * p["n"] + p["lam_t"] * p["tan"])
        c_n = p["lam_n"] - jnp.maximum(0.0, p["trial_n"])
        if self.friction == "none":
            c_t = p["lam_t"]
            return r_u, jnp.stack([c_n, c_t])
        elif self.friction == "sticking":  # no infinite bound in the arithmetic (NaN-free VJP)
            c_t = jnp.where(p["active"], c * p["slip"], p["lam_t"])
        else:
            safe = jnp.where(p["stick"], 1.0, p["az"])
            slip_eq = p["lam_t"] - p["bound"] * p["z"] / safe
            c_t = jnp.where(p["active"], jnp.where(p["stick"], c * p["slip"], slip_eq), p["lam_t"])
        # where a Dirichlet condition fixes the tangential motion, friction has nothing to act on
        c_t = jnp.where(p["frictionless"], p["lam_t"], c_t)
        return r_u, jnp.stack([c_n, c_t])

    def pair_status(self, die, x, lam, t, c, step: ContactStep, k):
        """(status OPEN/STICK/SLIP, normal n, tangent t, slip increment) at convergence."""
        p = self._parts(die, x, lam, t, c, step, k)
        in_contact = p["lam_n"] > 0.0
        if self.friction == "none":
            sticks = jnp.asarray(False)
        else:
            sticks = p["stick"] | p["frictionless"]  # a fixed node cannot slip
        status = jnp.where(in_contact, jnp.where(sticks, STICK, SLIP), OPEN)
        return status, p["n"], p["tan"], p["slip"]


def facet_terms(die, v, t, c):
    """Corner contact of one workpiece facet, v = (x_a (2), x_b (2), mu): (force residual
    on its two nodes (4,), complementarity residual (1,)).

    The facet's gap to the die's convex arcs g(x_a, x_b) (:meth:`RigidDie.facet_gap`)
    with a normal multiplier mu >= 0 (N, frictionless): C = mu - max(0, mu - c g), and the
    nodes' residuals gain -mu dg/dx (the die pushes the facet back along the arc's normal,
    shared between the nodes by where the arc touches)."""
    mu = v[4]

    def gap(xs):
        return die.facet_gap(xs[:2], xs[2:], t)[0]

    g, dg = jax.value_and_grad(gap)(v[:4])
    c_n = mu - jnp.maximum(0.0, mu - c * g)
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


def shear_bounds(m_factor, sigma_eq_nodes, areas):
    """b = m sigma_eq / sqrt(3) A per candidate (N)."""
    return m_factor * sigma_eq_nodes / jnp.sqrt(3.0) * areas
