"""What pauses a compiled chunk for the host: the triggers, one class each.

A trigger is a static, hashable object (:class:`jaxform.stepping.Stepper` holds a tuple of
them) that

* measures a value after each converged step inside the compiled chunk (traceable,
  :meth:`measure` of an :class:`AfterStep`), recorded in the outputs under its ``column``
  where it has one;
* fires on that value against its threshold (:meth:`fires`; a threshold of 0: never),
  the thresholds traced in :class:`jaxform.stepping.StepControl` (``thresholds``, in the
  order of the stepper's tuple), so that a new threshold compiles nothing;
* on the host, reads its configured threshold from the scene (:meth:`configured`: its
  config key) and arms the threshold for the steps on a new mesh (:meth:`armed`): a
  trigger that the new mesh still fires waits until it has become 10 % worse, so that a
  run cannot adapt on every step.

:data:`TRIGGERS` are all of them, each with its bit of the outputs' ``pause_cause``
(:func:`causes` names them).  The costly ones (a die corner's depth, a fold) are compiled
into a scene's steps only where the scene sets one (:func:`scene_triggers`).  The geometric
measures:

* :func:`corner_depth_ratio`: how deep a convex die corner reaches into a free-surface
  facet, over the facet's length (the die's rounded corners against the facets as the
  boundary walks them, :meth:`jaxform.dies.RigidDie.facet_gap`);
* :func:`fold_angle_deg`: the narrowest air-side angle between the two free-surface
  facets at an open contact candidate (180 deg on a straight surface, 270 at a square
  corner of the section, 0 where the surface has folded flat onto itself).

The fold angle here sees the candidates only (a wedge); the history
(:func:`jaxform.laps.fold_columns`) also measures pockets closing on the die.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import jax
import jax.numpy as jnp

from jaxform.assembly import Indices
from jaxform.geometry import min_quality

# the trigger bits of a paused step (outputs' ``pause_cause``)
QUALITY, STEPS, STROKE, CORNER, FOLD, CAPACITY = 1, 2, 4, 8, 16, 32
# not a trigger: the host remeshes after a step that failed (jaxform.simulation._rescued)
FAILED_STEP = 64
CAUSE_NAMES = {QUALITY: "quality", STEPS: "steps", STROKE: "stroke", CORNER: "die corner",
               FOLD: "fold", CAPACITY: "press capacity", FAILED_STEP: "failed step"}  # fmt: skip


# a mesh at this share of the quality threshold still serves a step where only the steps
# ahead would need a new one (:meth:`Armed.only_ahead`)
HOLDS = 0.5


def causes(bits: int) -> str:
    """The names of the triggers set in ``bits`` (e.g. 'quality+fold')."""
    return "+".join(name for bit, name in CAUSE_NAMES.items() if bits & bit) or "none"


@dataclass(frozen=True)
class AfterStep:
    """What a trigger may measure after a converged step, inside the compiled chunk: the
    nodal positions (mm), the indices, the die (None without one), the state, the row's
    stroke (mm) and force (N), and the chunk's converged steps so far."""

    positions: jax.Array
    idx: Indices
    die: object
    state: object
    stroke_mm: jax.Array
    force_N: jax.Array
    steps: jax.Array


def _remeshing(scene):
    """The scene's remesh settings where it remeshes, else None."""
    rm = scene.remesh
    return rm if rm is not None and rm.on else None


@dataclass(frozen=True)
class Trigger:
    """The protocol of a trigger (see the module docstring); subclasses set the class
    attributes and :meth:`measure`, and where the default does not fit :meth:`fires`,
    :meth:`configured` and :meth:`armed`."""

    bit: ClassVar[int]
    column: ClassVar[str | None] = None  # the outputs' column of the measured value
    costly: ClassVar[bool] = False  # compiled in only where the scene sets it
    key: ClassVar[str] = ""  # its [remesh] config key

    def measure(self, after: AfterStep) -> jax.Array:
        raise NotImplementedError

    def fires(self, value, threshold):
        """Whether ``value`` fires at ``threshold`` (traced; 0: never): below it."""
        return (threshold > 0.0) & (value < threshold)

    def configured(self, scene) -> float:
        """The threshold the scene sets (its ``[remesh]`` key; 0: off)."""
        rm = _remeshing(scene)
        return float(getattr(rm, self.key)) if rm is not None else 0.0

    def armed(self, configured: float, row: dict | None, quality_after: float | None) -> float:
        """The threshold for the steps on a new mesh (host): ``row`` is the row that paused
        (None at the start of the run), ``quality_after`` the new mesh's worst corner
        quality where it may still fire (None: it does not).  Default: the configured one."""
        return configured

    def for_chunk(self, configured: float, threshold: float, steps_since: int) -> float:
        """The threshold for the next chunk, ``steps_since`` converged steps after the
        last new mesh (host).  Default: unchanged."""
        return threshold


@dataclass(frozen=True)
class QualityBelow(Trigger):
    """An element's worst corner quality (:func:`jaxform.geometry.min_quality`) below the
    threshold: ``remesh.quality_below``, or ``mesh.rezone_quality`` for a scene that
    rezones."""

    bit: ClassVar[int] = QUALITY
    column: ClassVar[str] = "mesh_quality"
    key: ClassVar[str] = "quality_below"

    def measure(self, after: AfterStep):
        return min_quality(after.positions, after.idx.elements)

    def configured(self, scene) -> float:
        return super().configured(scene) if _remeshing(scene) else float(scene.rezone_quality)

    # the fraction of a new mesh's worst corner quality at which the trigger fires again
    # where that mesh is already below the trigger (the remesher could not make a better
    # corner there: a fin's tip, a flash's front).  Lower fractions (0.5, 0.7) cut the
    # remeshes of such a corner but let the two-stage disk's finisher fin distort until
    # its run failed (docs/processes.md, "Designing the blocker")
    helpless: ClassVar[float] = 0.9

    def armed(self, configured, row, quality_after):
        if quality_after is None or quality_after > configured:
            return configured
        return self.helpless * quality_after


@dataclass(frozen=True)
class EverySteps(Trigger):
    """Every ``remesh.every_steps`` converged steps on a mesh."""

    bit: ClassVar[int] = STEPS
    key: ClassVar[str] = "every_steps"

    def measure(self, after: AfterStep):
        return after.steps

    def fires(self, value, threshold):
        return (threshold > 0) & (value >= threshold)

    def for_chunk(self, configured, threshold, steps_since):
        # a mesh that has had its steps (one a run went back to) fires after the next one
        return max(configured - steps_since, 1) if configured else 0.0


@dataclass(frozen=True)
class EveryStroke(Trigger):
    """Every ``remesh.every_stroke_mm`` of ram stroke since the last new mesh."""

    bit: ClassVar[int] = STROKE
    key: ClassVar[str] = "every_stroke_mm"

    def measure(self, after: AfterStep):
        return after.stroke_mm

    def fires(self, value, threshold):
        return (threshold > 0.0) & (value >= threshold)

    def armed(self, configured, row, quality_after):
        stroke = float(row["stroke_mm"]) if row is not None else 0.0
        return stroke + configured if configured > 0 else 0.0


@dataclass(frozen=True)
class _ShapeTrigger(Trigger):
    """A geometric trigger that the new mesh still fires when it fired (the new mesh keeps
    the old boundary): it then waits until the measure is 10 % worse than on the row."""

    costly: ClassVar[bool] = True
    relax: ClassVar[float] = 1.0

    def armed(self, configured, row, quality_after):
        if row is None or not int(row["pause_cause"]) & self.bit:
            return configured
        worse = self.relax * float(row[self.column])
        return max(configured, worse) if self.relax > 1.0 else min(configured, worse)


@dataclass(frozen=True)
class CornerDepth(_ShapeTrigger):
    """A die corner deeper in a free-surface facet than ``remesh.corner_depth_ratio`` of
    its length (:func:`corner_depth_ratio`)."""

    bit: ClassVar[int] = CORNER
    column: ClassVar[str] = "corner_depth_ratio"
    key: ClassVar[str] = "corner_depth_ratio"
    relax: ClassVar[float] = 1.1

    def measure(self, after: AfterStep):
        if after.die is None:
            return jnp.zeros((), after.positions.dtype)
        return corner_depth_ratio(after.die, after.positions, after.idx, after.state.t)

    def fires(self, value, threshold):
        return (threshold > 0.0) & (value > threshold)


@dataclass(frozen=True)
class FoldBelow(_ShapeTrigger):
    """A free-surface fold narrower than ``remesh.fold_angle_deg`` (:func:`fold_angle_deg`)."""

    bit: ClassVar[int] = FOLD
    column: ClassVar[str] = "free_fold_deg"
    key: ClassVar[str] = "fold_angle_deg"
    relax: ClassVar[float] = 0.9

    def measure(self, after: AfterStep):
        return fold_angle_deg(after.positions, after.idx, after.state.contact_status)


@dataclass(frozen=True)
class PressCapacity(Trigger):
    """The ram force reaching the press capacity (``press.capacity_N``): the press stalls
    and the run ends on that step (:mod:`jaxform.presses`)."""

    bit: ClassVar[int] = CAPACITY

    def measure(self, after: AfterStep):
        return after.force_N

    def fires(self, value, threshold):
        return (threshold > 0.0) & (value >= threshold)

    def configured(self, scene) -> float:
        return float(scene.press.capacity_N) if scene.press is not None else 0.0


TRIGGERS = (QualityBelow(), EverySteps(), EveryStroke(), CornerDepth(), FoldBelow(),
            PressCapacity())  # fmt: skip


def scene_triggers(scene) -> tuple[Trigger, ...]:
    """The triggers compiled into the scene's steps: every cheap one (a threshold of 0
    leaves it off, and scenes that differ in their thresholds share a program) and the
    costly ones where the scene sets any of them (all of them, so that the scenes that
    measure the boundary's shape share one program too)."""
    costly = any(t.costly and t.configured(scene) > 0.0 for t in TRIGGERS)
    return tuple(t for t in TRIGGERS if costly or not t.costly)


@dataclass(frozen=True)
class Armed:
    """The triggers of a run with the thresholds its scene configures (host side):
    :meth:`thresholds` arms them for the steps on a mesh, :meth:`for_chunk` updates them
    before each chunk; both give the traced tuple of :class:`jaxform.stepping.StepControl`."""

    triggers: tuple[Trigger, ...]
    configured: tuple[float, ...]

    @classmethod
    def of(cls, scene, triggers: tuple[Trigger, ...]) -> Armed:
        return cls(triggers, tuple(t.configured(scene) for t in triggers))

    def thresholds(self, row: dict | None = None, quality_after: float | None = None) -> tuple:
        """The thresholds for the steps on a new mesh after the paused ``row`` (None: at
        the start) whose new mesh has the worst corner quality ``quality_after`` where it
        may still fire the quality trigger (None: it does not)."""
        return tuple(
            jnp.asarray(float(t.armed(c, row, quality_after)))
            for t, c in zip(self.triggers, self.configured)
        )

    def only_ahead(self, row: dict) -> bool:
        """Whether the paused ``row`` fired only triggers that adapt the mesh for the steps
        ahead: a schedule (steps, stroke), or the quality with the mesh still at least
        :data:`HOLDS` of the configured threshold (a fold, a die corner's depth, a worse
        mesh, the press capacity: no)."""
        bits = int(row["pause_cause"])
        if bits & ~(QUALITY | STEPS | STROKE):
            return False
        if not bits & QUALITY:
            return True
        return self.holds(row)

    def holds(self, row: dict) -> bool:
        """Whether the mesh of ``row`` is still at least :data:`HOLDS` of the configured
        quality threshold (True where no quality trigger is configured)."""
        configured = [c for t, c in zip(self.triggers, self.configured) if t.bit == QUALITY]
        if not configured or configured[0] <= 0.0:
            return True
        return float(row["mesh_quality"]) >= HOLDS * configured[0]

    def for_chunk(self, thresholds: tuple, steps_since: int) -> tuple:
        """``thresholds`` for the next chunk, ``steps_since`` steps after the last new mesh."""
        return tuple(
            jnp.asarray(t.for_chunk(c, h, steps_since))
            for t, c, h in zip(self.triggers, self.configured, thresholds)
        )


def off(triggers: tuple[Trigger, ...]) -> tuple:
    """Thresholds that leave every trigger off (:func:`jaxform.simulation.init`)."""
    return tuple(jnp.asarray(0.0) for _ in triggers)


def corner_depth_ratio(die, pos, idx: Indices, t):
    """The largest depth (mm) by which a convex arc of ``die`` (of any die of a set) at
    time t reaches into a free-surface facet, over that facet's length (0 where none
    reaches in)."""
    f = idx.contact_facets
    if f.shape[0] == 0 or all(d.points.shape[0] < 3 for d in die.members):  # no arc
        return jnp.zeros((), pos.dtype)
    p = pos[idx.contact_nodes]
    xa, xb = p[f[:, 0]], p[f[:, 1]]
    g, engaged = jax.vmap(lambda a, b: die.facet_gap(a, b, t))(xa, xb)
    length = jnp.sqrt(jnp.sum((xb - xa) ** 2, axis=1))
    depth = jnp.where(engaged & (g < 0.0), -g / jnp.maximum(length, 1e-300), 0.0)
    return jnp.max(depth)


def fold_angle_deg(pos, idx: Indices, status):
    """The smallest air-side angle (deg) between the facet into and the facet out of an
    open contact candidate (status 0) that has both; 180 where none has."""
    f = idx.contact_facets
    n_c = idx.contact_nodes.shape[0]
    if f.shape[0] == 0:
        return jnp.asarray(180.0, pos.dtype)
    prev = jnp.full(n_c, -1, f.dtype).at[f[:, 1]].set(f[:, 0])
    nxt = jnp.full(n_c, -1, f.dtype).at[f[:, 0]].set(f[:, 1])
    # open against every die: a node's candidates (one per die where they are (node, die)
    # pairs) share its status's largest
    node_status = jnp.zeros(pos.shape[0], status.dtype).at[idx.contact_nodes].max(status)
    ok = (prev >= 0) & (nxt >= 0) & (node_status[idx.contact_nodes] == 0)
    p = pos[idx.contact_nodes]
    e_in = p - p[jnp.maximum(prev, 0)]
    e_out = p[jnp.maximum(nxt, 0)] - p
    cross = e_in[:, 0] * e_out[:, 1] - e_in[:, 1] * e_out[:, 0]
    turn = jnp.arctan2(cross, jnp.sum(e_in * e_out, axis=1))
    angle = jnp.where(ok, jnp.degrees(jnp.pi + turn), 180.0)
    return jnp.min(angle)
