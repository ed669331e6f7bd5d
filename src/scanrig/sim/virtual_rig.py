"""A virtual rig implementing the rig protocol (``Cameras`` + ``LaserPositioner``) of scanrig.scan.

The scanning loop drives it exactly like hardware: ``move_to(beam)``, ``set_laser(on)``,
``grab()``. Every grabbed frame's ground truth (beam pose and true hit points) is recorded in
:attr:`VirtualRig.truth`, which the scan code never reads.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scanrig.geometry import Rig
from scanrig.sim.laser import BeamPose, trace_laser
from scanrig.sim.render import CameraView


@dataclass(frozen=True)
class FrameTruth:
    """Ground truth of one grabbed frame.

    Attributes
    ----------
    index : int
        Grab counter, from 0.
    beam : BeamPose or None
        Beam pose when the laser was on, else None.
    points : ndarray of shape (K, 3)
        True hit points, world metres.
    kinds : list of str
        ``"primary"`` or ``"secondary"`` per point.
    """

    index: int
    beam: BeamPose | None
    points: np.ndarray
    kinds: list


class VirtualRig:
    """Simulated cameras and laser positioner.

    Parameters
    ----------
    scene : Scene
    rig : Rig
        The true cameras.
    rng : numpy.random.Generator
        Source of image noise.
    workers : int, optional
        Processes that render the cameras' laser-free backgrounds at the first grab (one camera
        each; default :func:`scanrig.parallel.run_indexed`'s).
    """

    def __init__(self, scene, rig: Rig, rng: np.random.Generator, workers: int | None = None):
        self.scene = scene
        self.rig = rig
        self._rng = rng
        self._workers = workers
        self._views = [CameraView(cam, scene, rng=child) for cam, child in zip(rig.cameras, rng.spawn(len(rig)))]
        self._beam: BeamPose | None = None
        self._laser_on = False
        self.truth: list[FrameTruth] = []

    @property
    def names(self) -> list[str]:
        """Camera names in rig order."""
        return self.rig.names

    def move_to(self, beam) -> None:
        """Point the laser (any object with ``origin``, ``direction``, optional ``fan_axis``)."""
        self._beam = BeamPose.from_any(beam)

    def set_laser(self, on: bool) -> None:
        """Switch the laser on or off."""
        self._laser_on = bool(on)

    def grab(self, rng: np.random.Generator | None = None) -> dict[str, np.ndarray]:
        """One synchronised frame per camera (``name -> image``), recording its truth.

        Parameters
        ----------
        rng : numpy.random.Generator, optional
            Noise source for this frame only; by default the rig's own generator, drawn in grab
            order. A per-frame generator makes a frame independent of how many came before it
            (a resumed scan then renders the same frames as an uninterrupted one).
        """
        rng = self._rng if rng is None else rng
        self._render_backgrounds()
        trace = None
        if self._laser_on and self._beam is not None:
            trace = trace_laser(self._beam, self.scene.laser, self.scene)
        images = {view.camera.name: view.frame(trace, rng) for view in self._views}
        points = trace.truth_points if trace is not None else np.zeros((0, 3))
        kinds = trace.truth_kind if trace is not None else []
        self.truth.append(FrameTruth(len(self.truth), self._beam if trace is not None else None, points, kinds))
        return images

    def _render_backgrounds(self) -> None:
        """Render every camera's laser-free background (:attr:`CameraView.background_e`), the cameras
        in parallel, unless done; a process forked afterwards inherits them."""
        from scanrig.parallel import run_indexed

        todo = [view for view in self._views if "background_e" not in view.__dict__]
        if not todo:
            return
        for view, image in zip(todo, run_indexed(lambda i: todo[i].background_e, len(todo), self._workers)):
            view.background_e = image      # the cached property's value, computed in a worker
