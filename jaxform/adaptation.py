"""What the host loop does when a compiled chunk pauses: the adaptations of the mesh.

:func:`jaxform.simulation.simulate` steps a run on one mesh at a time (:class:`OnMesh`: the
scene, the reference its steps use, the scene the compiled steps run and its stepper).
When a trigger pauses a chunk (:mod:`jaxform.triggers`), the run's adaptation
(:func:`adaptation_of`) answers with an :class:`Adapted`: the mesh and state to go on
from, the columns of the paused row and the report of what it did:

* :class:`NoAdaptation`: one mesh for the whole run (only the press capacity pauses it,
  which ends the run);
* :class:`Rezoning`: the structured mesh's nodes moved (:func:`jaxform.rezone.rezone`),
  the run going on from the rezoned reference;
* :class:`Remeshing`: a new mesh (:func:`jaxform.remesh.remesh`), stepped padded to its
  capacity bucket (:func:`jaxform.capacity.padded`: a new mesh in the same bucket reuses
  the compiled program).

:class:`OwnedFactorization` is the factorization modified Newton keeps across chunks,
which the host loop owns: lent to each chunk, renewed on a new mesh, freed at the end.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import ClassVar

import jax
import numpy as np

from jaxform.capacity import Padded, padded
from jaxform.remesh import RemeshError, remesh
from jaxform.rezone import RezoneError, rezone
from jaxform.scenes import Inputs, Scene, analyzed
from jaxform.stepping import Stepper, stepper_of
from jaxform.triggers import causes


@dataclass(frozen=True)
class OnMesh:
    """A run on one mesh: ``scene`` (its mesh, sets and dofs), ``inputs`` the reference its
    steps use (the scene's; after rezoning, the rezoned one), ``padded`` the scene padded to
    its capacity bucket where the compiled steps run that (None: they run ``scene``), and
    the ``stepper`` of the scene the steps run."""

    scene: Scene
    inputs: Inputs
    stepper: Stepper
    padded: Padded | None = None

    @classmethod
    def of(cls, scene: Scene, pad: bool = False) -> OnMesh:
        """The run on ``scene``'s mesh, stepped on the scene itself (its pattern analysed
        where it is not yet) or, with ``pad``, padded to its capacity bucket."""
        if pad:
            p = padded(scene)
            return cls(scene, scene.inputs, stepper_of(p.scene), p)
        scene = analyzed(scene)
        return cls(scene, scene.inputs, stepper_of(scene))

    @property
    def stepped(self) -> Scene:
        """The scene the compiled steps run."""
        return self.scene if self.padded is None else self.padded.scene

    @property
    def step_inputs(self) -> Inputs:
        """The inputs the compiled steps take."""
        return self.inputs if self.padded is None else self.padded.scene.inputs

    def enter(self, state):
        """``state`` (on ``scene``) in the layout of the scene the steps run."""
        return state if self.padded is None else self.padded.state(state)

    def leave(self, state, outs: dict):
        """A chunk's end state and (host) outputs back on ``scene``."""
        if self.padded is None:
            return state, outs
        return self.padded.trim(state), self.padded.trim_outputs(outs)


class OwnedFactorization:
    """The factorization a Newton variant keeps across chunks (modified Newton's; none for
    full Newton), owned by the host loop: :meth:`lend` hands it to a chunk (which frees it
    when it refactors), :meth:`keep` takes back the one the chunk returns, :meth:`renew`
    frees it and starts one for a new mesh, :meth:`release` frees it at the end.  A
    factorization lent to a chunk that raised is lost, never freed twice.  (A host-side
    resource: the one mutable object of the loop.)"""

    def __init__(self, scene: Scene, dtype):
        self._scene, self._dtype, self._fac = scene, dtype, None
        self.renew(scene)

    def lend(self):
        """The factorization for the next chunk; a new empty one where the last chunk
        returned none (a chunk that stopped on a singular Jacobian frees its own)."""
        if self._fac is None:
            self._fac = self._empty(self._scene)
        fac, self._fac = self._fac, None
        return fac

    def _empty(self, scene: Scene):
        n = scene.model.layout.n_dofs
        return scene.newton.variant.factorization(scene.linear, n, self._dtype)

    def keep(self, fac) -> None:
        self._fac = fac

    def renew(self, scene: Scene) -> None:
        self.release()
        self._scene = scene
        self._fac = self._empty(scene)

    def release(self) -> None:
        if self._fac is not None:
            jax.block_until_ready(self._scene.linear.release(self._fac))
            self._fac = None


@dataclass(frozen=True)
class Adapted:
    """The answer to a paused step: the mesh and the state to go on from, the paused row's
    columns (``rezoned``, ``remeshed``, ``new_nodes``), the report (None: nothing done),
    the new mesh's worst corner quality where it may still fire the quality trigger (None:
    it does not; :meth:`jaxform.triggers.Armed.thresholds`), and for a new mesh the map
    that carried the state (``new_mesh``; :class:`jaxform.remesh.StateMap`).  ``failure``:
    why the adaptation failed (the run stops on the paused row; nothing else is set)."""

    mesh: OnMesh | None = None
    state: object = None
    row: dict = field(default_factory=dict)
    report: object = None
    quality_after: float | None = None
    new_mesh: bool = False
    transfer: object = None
    failure: str | None = None


@dataclass(frozen=True)
class NoAdaptation:
    """A run on the scene's own mesh from start to end."""

    reports: ClassVar[str] = ""  # the Result field that lists the reports

    def first_mesh(self, scene: Scene) -> OnMesh:
        return OnMesh.of(scene)

    def adapt(self, mesh: OnMesh, state, row: dict) -> Adapted:
        """Nothing to do: the run goes on as it is."""
        return Adapted(mesh, state)


@dataclass(frozen=True)
class Rezoning:
    """The structured mesh's nodes moved when an element's worst corner quality falls
    below ``mesh.rezone_quality`` (:mod:`jaxform.rezone`); a rezoning that could not raise
    the quality keeps the mesh and waits until the quality has fallen by another 10 %
    (:attr:`jaxform.triggers.QualityBelow.helpless`)."""

    reports: ClassVar[str] = "rezones"

    def first_mesh(self, scene: Scene) -> OnMesh:
        return OnMesh.of(scene)

    def adapt(self, mesh: OnMesh, state, row: dict) -> Adapted:
        try:
            state, inputs, report = rezone(mesh.scene, state, mesh.inputs)
        except RezoneError as err:
            return Adapted(failure=str(err))
        return Adapted(
            replace(mesh, inputs=inputs),
            state,
            row=dict(rezoned=int(report.improved)),
            report=report,
            quality_after=None if report.improved else report.quality_before,
        )


@dataclass(frozen=True)
class Remeshing:
    """A new mesh when a ``[remesh]`` trigger fires (:mod:`jaxform.remesh`), each mesh
    stepped padded to its capacity bucket; the state carried by the remesh's map."""

    settings: object  # the scene's RemeshConfig
    reports: ClassVar[str] = "remeshes"

    def first_mesh(self, scene: Scene) -> OnMesh:
        return OnMesh.of(scene, pad=True)

    def adapt(self, mesh: OnMesh, state, row: dict) -> Adapted:
        """The new mesh and the state on it; the padding to the bucket counts as part of
        the remesh's host time."""
        try:
            done = remesh(mesh.scene, state, self.settings)
        except RemeshError as err:
            return Adapted(failure=f"remeshing failed: {err}")
        start = time.perf_counter()
        new = OnMesh.of(done.scene, pad=True)
        report = replace(done.report, trigger=causes(int(row["pause_cause"])),
                         seconds=done.report.seconds + time.perf_counter() - start)  # fmt: skip
        return Adapted(new, done.state, row=dict(remeshed=1, new_nodes=report.nodes_after),
                       report=report, quality_after=report.quality_after, new_mesh=True,
                       transfer=done.transfer)  # fmt: skip


def adaptation_of(scene: Scene) -> NoAdaptation | Rezoning | Remeshing:
    """The scene's adaptation: remeshing where ``[remesh]`` sets a trigger, rezoning where
    ``mesh.rezone_quality`` > 0, else none."""
    if scene.remeshes:
        return Remeshing(scene.remesh)
    if scene.rezone_quality > 0.0:
        return Rezoning()
    return NoAdaptation()


def absolute(mesh: OnMesh, x: np.ndarray) -> np.ndarray:
    """Unknowns with the displacement measured from the scene's reference coordinates
    ``scene.inputs.coords`` (after rezoning the compiled step measures it from the rezoned
    reference ``mesh.inputs.coords``)."""
    shift = np.asarray(mesh.inputs.coords) - np.asarray(mesh.scene.inputs.coords)
    if not np.any(shift):
        return x
    x = np.array(x)
    mesh.scene.model.layout.nodal(x)[:, :2] += shift  # a view: shifts x in place
    return x
