"""Analysis of one rig on one object: per element, who sees it, how well, how densely.

A camera *uses* an element when it sees it (:func:`scanrig.design.visibility.view`) and the
element lies within the lens's depth of field around the focus distance (the distance from the
camera to the mounting region's ``look_at`` point). An element is *covered* when at least
``target.min_views`` cameras use it and its predicted sigma is within ``target.sigma_m``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scanrig.geometry.camera import Camera

from . import accuracy
from .elements import SurfaceElements
from .spec import DesignSpec
from .visibility import RayCaster, View, view


@dataclass(frozen=True)
class CameraTerms:
    """One camera's contribution to every element.

    Attributes
    ----------
    view : View
        Visibility geometry.
    in_focus : (N,) bool array
        Within the depth of field.
    used : (N,) bool array
        Seen and in focus.
    info : (N, 3, 3) float array
        Information ``J^T W J`` (1/m²), zero where not used.
    jtj : (N, 3, 3) float array
        ``J^T J`` (px²/m²), zero where not used.
    focal_px : float
        The camera's focal length, pixels.
    """

    view: View
    in_focus: np.ndarray
    used: np.ndarray
    info: np.ndarray
    jtj: np.ndarray
    focal_px: float


def camera_terms(camera: Camera, elements: SurfaceElements, caster: RayCaster, spec: DesignSpec) -> CameraTerms:
    """Visibility, focus and information of one camera for every element."""
    v = view(camera, elements, caster, np.radians(spec.target.max_incidence_deg))
    focal_length_m = camera.params[0] * spec.camera.pixel_pitch_m
    focus_m = float(np.linalg.norm(camera.center_world - np.asarray(spec.mounting.look_at)))
    near, far = accuracy.depth_of_field(focal_length_m, spec.camera.f_number,
                                        spec.camera.circle_of_confusion_px * spec.camera.pixel_pitch_m, focus_m)
    in_focus = (v.distance_m >= near) & (v.distance_m <= far)
    used = v.seen & in_focus
    info = np.zeros((len(elements), 3, 3))
    jtj = np.zeros((len(elements), 3, 3))
    idx = np.flatnonzero(used)
    if idx.size:
        sigma_px = accuracy.pixel_sigma_px(spec.camera, spec.laser)
        info[idx], jtj[idx] = accuracy.information(camera, elements.points[idx], sigma_px, spec.calibration)
    return CameraTerms(v, in_focus, used, info, jtj, float(camera.params[0]))


@dataclass(frozen=True)
class RigAnalysis:
    """Per-element and per-camera predictions for one rig.

    Attributes
    ----------
    elements : SurfaceElements
    camera_names : list of str
    n_views : (N,) int array
        Cameras using each element.
    sigma_m : (N,) float array
        Predicted largest-axis 1-sigma, metres (``inf`` below ``min_views``).
    speckle_floor_m : (N,) float array
        The same with detection noise and calibration error set to zero (speckle alone).
    triangulation_angle_rad : (N,) float array
        Largest angle between two lines of sight using the element (0 below two views).
    density_per_m2 : (N,) float array
        Predicted points per m² (0 where not covered by ``min_views``).
    covered : (N,) bool array
        ``n_views >= min_views`` and ``sigma_m <= target``.
    used : (n_cams, N) bool array
        Which camera uses which element.
    in_focus_fraction : (n_cams,) float array
        Area fraction of each camera's seen surface that is within its depth of field.
    """

    elements: SurfaceElements
    camera_names: list[str]
    n_views: np.ndarray
    sigma_m: np.ndarray
    speckle_floor_m: np.ndarray
    triangulation_angle_rad: np.ndarray
    density_per_m2: np.ndarray
    covered: np.ndarray
    used: np.ndarray
    in_focus_fraction: np.ndarray

    def fraction(self, mask: np.ndarray) -> float:
        """Area fraction of the surface where ``mask`` holds."""
        return float(self.elements.areas[mask].sum() / self.elements.total_area)

    @property
    def covered_fraction(self) -> float:
        """Area fraction covered within the target."""
        return self.fraction(self.covered)


def analyze_rig(cameras: list[Camera], elements: SurfaceElements, caster: RayCaster, spec: DesignSpec) -> RigAnalysis:
    """Predict coverage, uncertainty and sampling density of a rig.

    Parameters
    ----------
    cameras : list of Camera
        The rig.
    elements : SurfaceElements
        The object's surface.
    caster : RayCaster
        Built on the object's mesh.
    spec : DesignSpec
        Complete (after :func:`~scanrig.design.spec.default_spec`).

    Returns
    -------
    RigAnalysis
    """
    terms = [camera_terms(cam, elements, caster, spec) for cam in cameras]
    used = np.array([t.used for t in terms]).reshape(len(cameras), len(elements))
    n_views = used.sum(axis=0)
    min_views = spec.target.min_views
    sigma = accuracy.sigma_from_information(sum(t.info for t in terms), n_views, min_views)
    speckle_px = accuracy.speckle_sigma_px(spec.camera, spec.laser)
    floor = (accuracy.sigma_from_information(sum(t.jtj for t in terms), n_views, min_views) * speckle_px
             if speckle_px > 0 else np.zeros(len(elements)))
    angle = np.zeros(len(elements))
    for i in range(len(terms)):
        for j in range(i + 1, len(terms)):
            both = terms[i].used & terms[j].used
            cos = np.einsum("ij,ij->i", terms[i].view.direction[both], terms[j].view.direction[both])
            angle[both] = np.maximum(angle[both], np.arccos(np.clip(cos, -1.0, 1.0)))
    density = _density(terms, n_views >= min_views, spec)
    seen_area = np.array([elements.areas[t.view.seen].sum() for t in terms])
    in_focus_area = np.array([elements.areas[t.used].sum() for t in terms])
    with np.errstate(invalid="ignore", divide="ignore"):
        in_focus_fraction = np.where(seen_area > 0, in_focus_area / seen_area, 0.0)
    return RigAnalysis(elements, [c.name for c in cameras], n_views, sigma, floor, angle, density,
                       (n_views >= min_views) & (sigma <= spec.target.sigma_m), used, in_focus_fraction)


def _density(terms: list[CameraTerms], triangulable: np.ndarray, spec: DesignSpec) -> np.ndarray:
    """Predicted points per m² of surface.

    Spots are placed ``laser.step_m`` apart on the surface (the planner aims beams across the
    surface), so a triangulable element gets ``1 / step²``. A stripe gives one point per image
    line of the camera that resolves it best, so along the stripe the spacing is that camera's
    pixel footprint on the surface, ``d / (f_px cos(incidence))``; across stripes it is the step.
    """
    step = spec.laser.step_m
    if spec.laser.mode == "spot" or not terms:
        return np.where(triangulable, 1.0 / step**2, 0.0)
    footprint = np.full(triangulable.shape, np.inf)
    for t in terms:
        cam_footprint = np.full(triangulable.shape, np.inf)
        u = t.used
        cam_footprint[u] = t.view.distance_m[u] / (t.focal_px * t.view.cos_incidence[u])
        footprint = np.minimum(footprint, cam_footprint)
    return np.where(triangulable, 1.0 / (step * np.maximum(footprint, np.finfo(float).tiny)), 0.0)
