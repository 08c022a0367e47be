"""Rigid dies: profile geometry, motion, and the closest-point gap of a workpiece node.

A die is a rigid curve in the model's 2-D section (r-z or x-y, mm) that translates along
z.  Its profile is a polyline ``points`` (k >= 2 points at t = 0) walked so that the
workpiece lies on the *right-hand side* of the direction of travel; for a top die walked
from the axis outward that is below it.  The first and last segments are extended to
infinity, so a two-point profile is an infinite straight die (the flat die).  Splines are
sampled into fine polylines at set-up (:func:`catmull_rom`).

Rounded vertices (a C1 die surface).  Every interior vertex where the profile turns by
theta is replaced by the circular arc tangent to both segments, with tangent length
l = min(half the shorter adjacent segment, R tan(|theta|/2)), R = ``corner_radius``
(``die.corner_radius_mm``): the arc radius is R where the segments are long enough (a
sharp corner of the polyline becomes a fillet of radius R) and smaller where they are
not; a polyline that samples a fillet of radius r in steps of theta (with R >= r) becomes
the concentric arc through the chords' midpoints, radius r cos(theta/2) (22.5 deg steps:
the surface moves by 1.9 % of r at the vertices), and a sampled spline likewise.  Why: with sharp
vertices the contact normal of a node *at* a vertex is not defined (the gap is |x - v|
there, a cone), so a node that the flow presses into a die corner, concave (the last
corners of a closed die to fill) or convex, can be in equilibrium only with a force
inside the normal cone, which one multiplier along one normal cannot carry: Newton then
converges at best linearly (closed die, 10x10: the outer corner node at 2e-10 mm from a
vertex, residual halving per iteration).  On the rounded profile every surface point has
one normal and the node finds the point whose normal matches its force.

Motion: the die's downward travel d(t) (mm) is linear interpolation in a table
``path_time_s -> path_travel_mm`` (constant speed is a two-row table), or a closed-form
``motion`` (a crank press, :mod:`jaxform.presses`); its position at time t is the profile
shifted by (0, -d(t)).

Gap: for a node at x the closest point q on the shifted rounded profile is found over all
straight pieces and arcs at once (no search state, so a node slides from one piece to
the next without any switching logic); g = (x - q) . n(q) with n(q) the profile normal at
q pointing to the workpiece.  The profile is C1, so g and n are continuous along it and g
is differentiable near it (away from the centres of concave arcs, a radius away from the
die).  The unit tangent is the normal turned by +90 deg (for a top die walked outward: +r).

Each die owns its friction law (:mod:`jaxform.contact`: Frictionless, Coulomb(mu),
Shear(m), Sticking), whose coefficients are arguments of the compiled step and can be
differentiated; a die set gives a node the law of the die that holds it.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import jax
import jax.numpy as jnp
import numpy as np

from jaxform.contact import FrictionLaw, Frictionless, pick_law
from jaxform.tables import interp_table


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class RigidDie:
    points: jax.Array  # (k, 2) profile at t = 0 (mm); workpiece on the right of the walk
    path_time_s: jax.Array  # (m,) increasing times (s), first 0
    path_travel_mm: jax.Array  # (m,) downward travel at those times (mm), first 0
    friction: FrictionLaw  # the die-workpiece friction law (its coefficients traced)
    corner_radius: jax.Array  # radius R of the arcs that round the vertices (mm), > 0
    # the rounded profile of `points` at t = 0 (:func:`rounded_profile`), computed once per
    # step by :meth:`prepared` (a step's gaps are evaluated at many sites of its program,
    # each of which would round the profile again); None: rounded where a gap needs it
    profile: dict | None = None
    # a closed-form motion (:class:`jaxform.presses.CrankMotion`) that replaces the path
    # table where set (a crank press); None: the table
    motion: object = None

    def prepared(self) -> RigidDie:
        """The die with its rounded profile computed (translation-invariant: a gap at time
        t is the gap of x - offset(t) against it)."""
        return replace(self, profile=rounded_profile(self.points, self.corner_radius))

    def travel(self, t):
        """Downward travel d(t) in mm (linear in the table; constant past its ends), or
        the die's closed-form motion where it has one."""
        if self.motion is not None:
            return self.motion.travel(t)
        return interp_table(t, self.path_time_s, self.path_travel_mm)

    def travel_at(self, t) -> float:
        """:meth:`travel` on the host (NumPy) for a time t (s): for post-processing, where
        one JAX call per history row would dispatch (and first compile) a small program."""
        if self.motion is not None:
            return self.motion.travel_at(t)
        return float(np.interp(t, np.asarray(self.path_time_s), np.asarray(self.path_travel_mm)))

    def offset(self, t):
        d = self.travel(t)
        return jnp.stack([jnp.zeros_like(d), -d])

    def gap(self, x, t):
        """(g, n, tangent) of a node at current position x (2,) at time t."""
        off = self.offset(t)
        return closest_point_gap(self.points, self.corner_radius, x - off, self.profile)

    def facet_gap(self, xa, xb, t):
        """(g, engaged) of the workpiece facet xa -> xb against the convex arcs at time t
        (:func:`corner_gap`)."""
        off = self.offset(t)
        return corner_gap(self.points, self.corner_radius, xa - off, xb - off, self.profile)

    @property
    def members(self) -> tuple[RigidDie, ...]:
        """The rigid dies of the scene (this one)."""
        return (self,)

    names = ("top",)  # as a DieSet's: the one die is the top die, pressing from above
    from_above = (True,)

    def stroke(self, t):
        """The ram stroke's share made by the dies at time t (mm): the travel."""
        return self.travel(t)

    def stroke_at(self, t) -> float:
        return self.travel_at(t)

    def frame(self, x, t, t_old) -> DieFrame:
        """What contact reads at a node at x and time t (:class:`DieFrame`)."""
        g, n, tan = self.gap(x, t)
        move = self.offset(t) - self.offset(t_old)
        return DieFrame(g=g, n=n, tan=tan, move=move, friction=self.friction,
                        which=jnp.zeros((), jnp.int32))  # fmt: skip

    def member_frame(self, x, t, t_old, which) -> DieFrame:
        """The frame of die ``which`` (the one die: :meth:`frame`)."""
        return self.frame(x, t, t_old)

    def facet_frame(self, xa, xb, t):
        """(g, engaged, which die) of a facet against the convex arcs (:meth:`facet_gap`)."""
        g, engaged = self.facet_gap(xa, xb, t)
        return g, engaged, jnp.zeros((), jnp.int32)

    def replace_each(self, fn) -> RigidDie:
        """The die with ``fn`` applied (as for every member of a :class:`DieSet`)."""
        return fn(self)

    def replace_top(self, fn) -> RigidDie:
        """The die with ``fn`` applied (as for the top die of a :class:`DieSet`)."""
        return fn(self)

    def with_members(self, dies) -> RigidDie:
        """The die ``dies[0]`` (as a :class:`DieSet` with its dies replaced)."""
        return dies[0]


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class DieFrame:
    """The die surface a workpiece node faces: the nearest die's gap g (mm), its normal n
    and tangent (2,), the die's displacement over the step (2,) (mm: the slip is measured
    against it), its friction law (:func:`jaxform.contact.pick_law`), and which die it
    is (index)."""

    g: jax.Array
    n: jax.Array
    tan: jax.Array
    move: jax.Array
    friction: FrictionLaw
    which: jax.Array


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class DieSet:
    """Several rigid dies (a top die, a bottom die, a mandrel or side die), each with its
    own profile, path and friction, behind the one-die interface contact uses.

    A workpiece node faces the die with the least gap (:meth:`frame`): its normal, its
    tangent, its motion over the step for the slip, and its friction law.  Every
    node is a candidate against every die, so a node may leave one die and meet another
    (material flowing from the bottom die into the top die's flash land).  The choice is
    piecewise constant, so derivatives hold away from the switch (where two dies are
    equally near, which a node in contact never is: it touches one die with g = 0 and the
    others lie a finite distance away).

    The first die is the ram (the top die, moving down); the one named ``bottom``, where
    there is one, the anvil below the workpiece: the stroke is their closure (top travel
    minus the bottom die's, whose travel is counted downward like every die's: negative
    when it rises)."""

    dies: tuple[RigidDie, ...]
    names: tuple[str, ...] = field(metadata=dict(static=True))  # "top", "bottom", "side"

    @property
    def from_above(self) -> tuple[bool, ...]:
        """Per die: whether it presses from above (all but the bottom die)."""
        return tuple(n != "bottom" for n in self.names)

    @property
    def members(self) -> tuple[RigidDie, ...]:
        return self.dies

    @property
    def top(self) -> RigidDie:
        return self.dies[0]

    def _closure(self, travel):
        if "bottom" not in self.names:
            return travel(self.dies[0])
        return travel(self.dies[0]) - travel(self.dies[self.names.index("bottom")])

    def travel(self, t):
        """The top die's downward travel (mm)."""
        return self.dies[0].travel(t)

    def travel_at(self, t) -> float:
        return self.dies[0].travel_at(t)

    def stroke(self, t):
        """The ram stroke at time t (mm): the closure of the top and bottom dies."""
        return self._closure(lambda d: d.travel(t))

    def stroke_at(self, t) -> float:
        return float(self._closure(lambda d: d.travel_at(t)))

    def _pick(self, values, k):
        return jnp.stack(values)[k]

    def frame(self, x, t, t_old) -> DieFrame:
        frames = [d.frame(x, t, t_old) for d in self.dies]
        k = jnp.argmin(jnp.stack([f.g for f in frames])).astype(jnp.int32)
        pick = {name: self._pick([getattr(f, name) for f in frames], k)
                for name in ("g", "n", "tan", "move")}  # fmt: skip
        return DieFrame(**pick, friction=pick_law([d.friction for d in self.dies], k), which=k)

    def member_frame(self, x, t, t_old, which) -> DieFrame:
        """The frame of die ``which`` (a traced index): a (node, die) pair's candidate
        (:class:`jaxform.contact.EachDie`) faces its own die, near or not."""
        frames = [d.frame(x, t, t_old) for d in self.dies]
        k = jnp.asarray(which, jnp.int32)
        pick = {name: self._pick([getattr(f, name) for f in frames], k)
                for name in ("g", "n", "tan", "move")}  # fmt: skip
        return DieFrame(**pick, friction=pick_law([d.friction for d in self.dies], k), which=k)

    def gap(self, x, t):
        """(g, n, tangent) of the nearest die at time t."""
        f = self.frame(x, t, t)
        return f.g, f.n, f.tan

    def facet_frame(self, xa, xb, t):
        """(g, engaged, which die): the least gap of the facet to any die's convex arcs."""
        parts = [d.facet_gap(xa, xb, t) for d in self.dies]
        g = jnp.stack([p[0] for p in parts])
        engaged = jnp.stack([p[1] for p in parts])
        k = jnp.argmin(jnp.where(engaged, g, jnp.inf)).astype(jnp.int32)
        return jnp.where(jnp.any(engaged), g[k], g[0]), jnp.any(engaged), k

    def facet_gap(self, xa, xb, t):
        g, engaged, _ = self.facet_frame(xa, xb, t)
        return g, engaged

    def prepared(self) -> DieSet:
        """The set with every die's rounded profile computed (:meth:`RigidDie.prepared`)."""
        return self.replace_each(lambda d: d.prepared())

    def replace_each(self, fn) -> DieSet:
        """The set with ``fn`` applied to every die (a friction coefficient or a speed
        given for the scene holds for every die)."""
        return replace(self, dies=tuple(fn(d) for d in self.dies))

    def replace_top(self, fn) -> DieSet:
        """The set with ``fn`` applied to the top die (the design group ``die``)."""
        return replace(self, dies=(fn(self.dies[0]), *self.dies[1:]))

    def with_members(self, dies) -> DieSet:
        """The set with its dies replaced by ``dies`` (one per die, in order)."""
        return replace(self, dies=tuple(dies))


def _right_normals(t):
    """Unit normals on the workpiece side (right of the walk) of unit directions t."""
    return jnp.stack([t[..., 1], -t[..., 0]], axis=-1)


def rounded_profile(points, corner_radius):
    """Pieces of the rounded profile: per segment j its start point, unit direction,
    length range [lo, hi] of its straight part; per interior vertex i the arc's centre,
    radius, tangent points a (on the incoming segment), b (outgoing) and the turn sign
    (+1: left turn, a convex die corner; -1: right turn, concave)."""
    d = points[1:] - points[:-1]
    length = jnp.sqrt(jnp.sum(d * d, axis=1))
    t = d / length[:, None]
    t0, t1 = t[:-1], t[1:]
    cross = t0[:, 0] * t1[:, 1] - t0[:, 1] * t1[:, 0]
    theta = jnp.arctan2(cross, jnp.sum(t0 * t1, axis=1))
    tan_half = jnp.tan(0.5 * jnp.abs(theta))
    turns = tan_half > 1e-12
    safe_tan = jnp.where(turns, tan_half, 1.0)
    ell = jnp.where(
        turns,
        jnp.minimum(0.5 * jnp.minimum(length[:-1], length[1:]), corner_radius * tan_half),
        0.0,
    )
    rho = ell / safe_tan
    sign = jnp.where(cross >= 0.0, 1.0, -1.0)
    a = points[1:-1] - ell[:, None] * t0
    b = points[1:-1] + ell[:, None] * t1
    centre = a - (sign * rho)[:, None] * _right_normals(t0)
    lo = jnp.concatenate([jnp.array([-jnp.inf]), ell])  # straight part of segment j
    hi = jnp.concatenate([length[:-1] - ell, jnp.array([jnp.inf])])
    return dict(
        start=points[:-1],
        t=t,
        lo=lo,
        hi=hi,
        centre=centre,
        rho=rho,
        a=a,
        b=b,
        sign=sign,
        turns=turns,
    )


def closest_point_gap(points, corner_radius, x, profile=None):
    """(g, n, tangent) of x against the rounded profile (see the module docstring);
    ``profile``: :func:`rounded_profile` of (points, corner_radius) if already computed."""
    pr = rounded_profile(points, corner_radius) if profile is None else profile
    # straight pieces
    s = jnp.clip(jnp.sum((x - pr["start"]) * pr["t"], axis=1), pr["lo"], pr["hi"])
    q_seg = pr["start"] + s[:, None] * pr["t"]
    n_seg = _right_normals(pr["t"])
    dist_seg = jnp.sum((x - q_seg) ** 2, axis=1)
    # arcs
    v = x - pr["centre"]
    r2 = jnp.sum(v * v, axis=1)
    r = jnp.sqrt(jnp.where(r2 > 0.0, r2, 1.0))
    u = v / r[:, None]
    sg = pr["sign"]

    def cross2(p, q):
        return p[:, 0] * q[:, 1] - p[:, 1] * q[:, 0]

    within = (
        (sg * cross2(pr["a"] - pr["centre"], v) >= 0.0)
        & (sg * cross2(v, pr["b"] - pr["centre"]) >= 0.0)
        & pr["turns"]
        & (r2 > 0.0)
    )
    q_arc = pr["centre"] + pr["rho"][:, None] * u
    n_arc = sg[:, None] * u
    dist_arc = jnp.where(within, (r - pr["rho"]) ** 2, jnp.inf)
    dist = jnp.concatenate([dist_seg, dist_arc])
    q = jnp.concatenate([q_seg, q_arc])
    normals = jnp.concatenate([n_seg, n_arc])
    i = jnp.argmin(dist)
    n = normals[i]
    g = jnp.sum((x - q[i]) * n)
    tangent = jnp.stack([-n[1], n[0]])
    return g, n, tangent


def has_convex_corner(points, corner_radius) -> bool:
    """Whether the rounded profile has a convex arc (a left turn: the die bulges into the
    workpiece side), the only place a die can reach between two contact nodes."""
    pr = rounded_profile(jnp.asarray(points, dtype=float), jnp.asarray(float(corner_radius)))
    return bool(np.any(np.asarray(pr["turns"]) & (np.asarray(pr["sign"]) > 0)))


def corner_gap(points, corner_radius, xa, xb, profile=None):
    """(g, engaged) of the workpiece facet xa -> xb (material on its left) against the
    convex arcs of the rounded profile (``profile``: as for :func:`closest_point_gap`).

    For each convex arc the point deepest into the facet's material side is the arc point
    whose outward normal is minus the facet's (or, outside the arc's span, the nearer
    end); g is its distance above the facet's line (mm, < 0: the die reaches into the
    material), over the arcs whose deepest point lies strictly between the facet's nodes
    (at a node the node's own contact condition holds it, and g equals that node's gap,
    so taking an arc in or out changes nothing) and less than half a facet below it
    (farther arcs belong to other parts of the surface).  ``engaged`` is False where no
    arc qualifies; g is then the facet length (positive, inactive).  Over the arcs that
    qualify g is a soft minimum (at most SOFT x length x log(n) below the least g, never
    above it): under a facet parallel to a straight piece between two arcs, the two arc
    ends lie at one depth and a hard minimum would move the facet's force from one node to
    the other in a jump (Newton then cycles).

    Where the deepest point nears one of the facet's nodes (within END_SHARE of its
    length) the facet lets go of the arc gradually: g rises linearly to the facet length
    (inactive) at the node.  There the node's own condition holds the die, and a facet
    condition that switched off as the point crossed the node made the multiplier jump and
    Newton cycle (docs/remeshing.md, generated dies).  The arc may then reach past the
    chord near the node by up to (END_SHARE length)^2 / (2 rho)."""
    pr = rounded_profile(points, corner_radius) if profile is None else profile
    d = xb - xa
    length = jnp.sqrt(jnp.sum(d * d))
    tau = d / length
    n_f = jnp.stack([tau[1], -tau[0]])  # right of the facet: out of the material
    c, rho = pr["centre"], pr["rho"]
    deep = c - rho[:, None] * n_f[None, :]

    def cross2(p, q):
        return p[:, 0] * q[:, 1] - p[:, 1] * q[:, 0]

    v = jnp.broadcast_to(-n_f, c.shape)
    within = (cross2(pr["a"] - c, v) >= 0.0) & (cross2(v, pr["b"] - c) >= 0.0)
    end = jnp.where((pr["a"] @ n_f <= pr["b"] @ n_f)[:, None], pr["a"], pr["b"])
    p = jnp.where(within[:, None], deep, end)
    xi = (p - xa) @ tau / length
    g = (p - xa) @ n_f
    # near a node the facet lets go of the arc gradually (see the docstring)
    g = g + (length - g) * jnp.clip((END_SHARE - jnp.minimum(xi, 1.0 - xi)) / END_SHARE, 0.0, 1.0)
    # the die surface at p faces the facet (its normal within 60 deg of the facet's):
    # an arc end round the workpiece's corner belongs to the neighbouring facet
    safe_rho = jnp.where(pr["turns"], rho, 1.0)
    faces = -((p - c) @ n_f) / safe_rho > 0.5
    ok = pr["turns"] & (pr["sign"] > 0) & faces & (xi > 0.0) & (xi < 1.0) & (g > -0.5 * length)
    engaged = jnp.any(ok)
    scale = SOFT * length
    # the soft minimum over the qualifying arcs only: taking the facet length of the
    # others as their g made the weights underflow to 0 (g = inf) where every qualifying
    # arc lies more than a facet length away
    # (initial: a straight two-point die has no arc at all)
    g_min = jnp.where(engaged, jnp.min(jnp.where(ok, g, jnp.inf), initial=jnp.inf), length)
    g_ok = jnp.where(ok, g, g_min)
    weights = jnp.where(ok, jnp.exp(-(g_ok - g_min) / scale), 0.0)
    soft = g_min - scale * jnp.log(jnp.where(engaged, jnp.sum(weights), 1.0))
    return jnp.where(engaged, soft, length), engaged


SOFT = 1e-3  # width of the soft minimum over the arcs, as a fraction of the facet length
END_SHARE = 0.1  # a facet lets go of an arc over this share of its length next to a node


# one compiled call (eagerly, its few dozen small operations would each compile)


def rounded_polyline(points, corner_radius, per_arc: int = 16):
    """The rounded profile as a polyline (traceable, differentiable in ``points`` and
    ``corner_radius``): the first point, per interior vertex ``per_arc + 1`` points on its
    arc from the tangent point a to b at equal angles (a vertex that does not turn: the
    vertex repeated), the last point; the points :func:`sample_rounded` draws."""
    pr = rounded_profile(points, corner_radius)
    t0, t1 = pr["t"][:-1], pr["t"][1:]
    cross = t0[:, 0] * t1[:, 1] - t0[:, 1] * t1[:, 0]
    theta = jnp.arctan2(cross, jnp.sum(t0 * t1, axis=1))  # the turn, as rounded_profile's
    ang = theta[:, None] * jnp.linspace(0.0, 1.0, per_arc + 1)[None, :]
    cos, sin = jnp.cos(ang)[..., None], jnp.sin(ang)[..., None]
    v = (pr["a"] - pr["centre"])[:, None, :]  # the radius to a, turned by s theta
    arcs = pr["centre"][:, None, :] + cos * v + sin * jnp.stack([-v[..., 1], v[..., 0]], -1)
    return jnp.concatenate([points[:1], arcs.reshape(-1, 2), points[-1:]], axis=0)


# one compiled call (eagerly, its few dozen small operations would each compile)
_rounded_polyline_jit = jax.jit(rounded_polyline, static_argnums=2)


def sample_rounded(points, corner_radius, per_arc: int = 16) -> np.ndarray:
    """The rounded profile as a dense polyline (NumPy; for plots and cavity volumes):
    :func:`rounded_polyline`, a vertex that does not turn once."""
    poly = np.asarray(
        _rounded_polyline_jit(
            jnp.asarray(points, dtype=float), jnp.asarray(float(corner_radius)), per_arc
        )
    )
    return poly[np.r_[True, np.any(np.diff(poly, axis=0) != 0.0, axis=1)]]


# ----------------------------------------------------------------------------------
# set-up helpers (NumPy)


class DieError(ValueError):
    pass


def catmull_rom(points: np.ndarray, per_span: int = 16) -> np.ndarray:
    """Sample the uniform Catmull-Rom spline through ``points`` (C1, passes through every
    point; end tangents by reflection) into a polyline with ``per_span`` pieces per span."""
    p = np.asarray(points, dtype=float)
    ext = np.vstack([2 * p[0] - p[1], p, 2 * p[-1] - p[-2]])
    u = np.linspace(0.0, 1.0, per_span, endpoint=False)[:, None]
    out = []
    for i in range(1, len(ext) - 2):
        p0, p1, p2, p3 = ext[i - 1], ext[i], ext[i + 1], ext[i + 2]
        out.append(
            0.5
            * (
                2 * p1
                + (-p0 + p2) * u
                + (2 * p0 - 5 * p1 + 4 * p2 - p3) * u**2
                + (-p0 + 3 * p1 - 3 * p2 + p3) * u**3
            )
        )
    out.append(p[-1:])
    return np.vstack(out)


def check_profile(points: np.ndarray, key: str, workpiece_below: bool = True) -> np.ndarray:
    """``points`` as a (k, 2) array, or DieError naming ``key`` and what is wrong: fewer
    than 2 points, non-finite or coinciding points, segments that cross (a self-intersecting
    profile), or (``workpiece_below``) a walk with the workpiece side (below a top die) on
    its left."""
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 2 or p.shape[0] < 2:
        raise DieError(
            f"{key}: must be a list of at least 2 [r_mm, z_mm] points, got shape {p.shape}"
        )
    if not np.all(np.isfinite(p)):
        raise DieError(f"{key}: points must be finite")
    seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
    if np.any(seg <= 1e-9):
        k = int(np.argmin(seg))
        raise DieError(f"{key}: points {k} and {k + 1} coincide (segments must have length > 0)")
    d = np.diff(p, axis=0) / seg[:, None]
    cross = d[:-1, 0] * d[1:, 1] - d[:-1, 1] * d[1:, 0]
    back = np.nonzero((np.abs(cross) <= 1e-9) & (np.sum(d[:-1] * d[1:], axis=1) < 0.0))[0]
    if back.size:
        k = int(back[0])
        raise DieError(
            f"{key}: segment {k + 1}-{k + 2} runs back along segment {k}-{k + 1} (the "
            f"profile turns by 180 deg at point {k + 1}); a die profile is a walk that "
            f"never retraces itself"
        )
    crossing = first_crossing(p)
    if crossing is not None:
        i, j = crossing
        raise DieError(
            f"{key}: segment {i}-{i + 1} crosses segment {j}-{j + 1}: the profile "
            f"must not intersect itself"
        )
    if workpiece_below and side_of(p, below_probe(p)) <= 0.0:
        raise DieError(
            f"{key}: the workpiece (below the die) lies on the left of the walk "
            f"from point 0 to point {len(p) - 1}; list the points from the axis "
            f"outward, with the workpiece on the right (reverse their order)"
        )
    return p


def first_crossing(p: np.ndarray) -> tuple[int, int] | None:
    """(i, j), i < j - 1, of the first pair of non-neighbouring segments of the polyline p
    that touch or cross (the end segments taken as drawn), or None."""
    a, b = p[:-1], p[1:]
    i, j = np.triu_indices(len(a), k=2)
    if i.size == 0:
        return None

    def orient(o, q, r):
        return np.sign(
            (q[:, 0] - o[:, 0]) * (r[:, 1] - o[:, 1]) - (q[:, 1] - o[:, 1]) * (r[:, 0] - o[:, 0])
        )

    d1, d2 = orient(a[i], b[i], a[j]), orient(a[i], b[i], b[j])
    d3, d4 = orient(a[j], b[j], a[i]), orient(a[j], b[j], b[i])
    proper = (d1 * d2 < 0) & (d3 * d4 < 0)

    def on_segment(o, q, r):  # r collinear with o-q: within its bounding box
        return ((np.minimum(o, q) - 1e-12 <= r) & (r <= np.maximum(o, q) + 1e-12)).all(axis=1)

    touch = (
        ((d1 == 0) & on_segment(a[i], b[i], a[j]))
        | ((d2 == 0) & on_segment(a[i], b[i], b[j]))
        | ((d3 == 0) & on_segment(a[j], b[j], a[i]))
        | ((d4 == 0) & on_segment(a[j], b[j], b[i]))
    )
    hit = np.nonzero(proper | touch)[0]
    return None if hit.size == 0 else (int(i[hit[0]]), int(j[hit[0]]))


def below_probe(p: np.ndarray) -> np.ndarray:
    """A point well below the profile (where a top die's workpiece is)."""
    extent = max(float(np.ptp(p[:, 0])), float(np.ptp(p[:, 1])), 1.0)
    return np.array([0.5 * (p[:, 0].min() + p[:, 0].max()), p[:, 1].min() - extent])


def side_of(p: np.ndarray, x: np.ndarray) -> float:
    """Signed distance of x from the sharp polyline p with its end segments extended to
    infinity: > 0 on the right of the walk.  At a vertex the sign comes from the sum of
    the two segment normals (the pseudo-normal), which is right for a simple polyline."""
    d = p[1:] - p[:-1]
    length = np.linalg.norm(d, axis=1)
    t = d / length[:, None]
    n = np.column_stack([t[:, 1], -t[:, 0]])
    s = np.sum((x - p[:-1]) * t, axis=1)
    lo = np.r_[-np.inf, np.zeros(len(d) - 1)]
    hi = np.r_[length[:-1], np.inf]
    sc = np.clip(s, lo, hi)
    q = p[:-1] + sc[:, None] * t
    k = int(np.argmin(np.sum((x - q) ** 2, axis=1)))
    normal = n[k]
    if sc[k] == hi[k] and k + 1 < len(d):  # at vertex k + 1
        normal = n[k] + n[k + 1]
    elif sc[k] == lo[k] and k > 0:  # at vertex k
        normal = n[k - 1] + n[k]
    dist = float(np.linalg.norm(x - q[k]))
    return dist if float(np.dot(x - q[k], normal)) > 0.0 else -dist


def check_clearance(
    points: np.ndarray, boundary: np.ndarray, key: str, tol_mm: float = 1e-9
) -> None:
    """DieError naming ``key`` if a workpiece boundary point (``boundary``: (n, 2), mm)
    lies inside the die at t = 0 (on the left of the sharp profile by more than tol_mm):
    the run would start with the die overlapping the workpiece."""
    depth = np.array([side_of(points, x) for x in boundary])
    k = int(np.argmin(depth))
    if depth[k] < -tol_mm:
        r, z = boundary[k]
        raise DieError(
            f"{key}: the die overlaps the workpiece at t = 0: its point ({r:g}, "
            f"{z:g}) mm lies {-depth[k]:.4g} mm inside the die; the profile must "
            f"start on or above the workpiece"
        )


def check_clearance_of_facets(
    points: np.ndarray, coords: np.ndarray, facets: np.ndarray, key: str
) -> None:
    """:func:`check_clearance` of the workpiece facets ``facets`` ((m, 2) node pairs of
    ``coords``, mm), each sampled at 9 points, to 1e-9 of the workpiece's size."""
    s = np.linspace(0.0, 1.0, 9)[None, :, None]
    a, b = coords[facets[:, 0]][:, None], coords[facets[:, 1]][:, None]
    pts = (a + s * (b - a)).reshape(-1, 2)
    check_clearance(points, pts, key, 1e-9 * float(np.ptp(coords, axis=0).max()))


def time_at_travel(times: np.ndarray, travel: np.ndarray, target: float, key: str) -> float:
    """Inverse of the path table (the end time of a run that stops at ``target`` mm)."""
    if target > travel[-1] + 1e-12:
        raise DieError(
            f"{key}: the path ends at travel {travel[-1]:g} mm, before the required {target:g} mm"
        )
    k = int(np.searchsorted(travel, target - 1e-12))
    k = max(k, 1)
    t0, t1, d0, d1 = times[k - 1], times[k], travel[k - 1], travel[k]
    return float(t0 + (target - d0) * (t1 - t0) / (d1 - d0)) if d1 > d0 else float(t1)


def make_die(
    points,
    times,
    travel,
    friction: FrictionLaw | None = None,
    corner_radius: float = 0.2,
    motion=None,
) -> RigidDie:
    """A rigid die from its profile and path table (``friction``: its law, default
    frictionless)."""
    if not corner_radius > 0.0:
        raise DieError(f"corner radius {corner_radius!r} mm: must be > 0")
    return RigidDie(
        points=jnp.asarray(points, dtype=float),
        path_time_s=jnp.asarray(times, dtype=float),
        path_travel_mm=jnp.asarray(travel, dtype=float),
        friction=Frictionless() if friction is None else friction,
        corner_radius=jnp.asarray(float(corner_radius)),
        motion=motion,
    )
