"""Designing a rig end to end: check the inputs, search the cameras, analyse the result.

>>> import numpy as np, trimesh
>>> from scanrig.design import DesignSpec, design_rig
>>> mesh = trimesh.creation.box((0.2, 0.2, 0.1))
>>> result = design_rig(mesh, 3, DesignSpec(), rng=np.random.default_rng(0))
>>> len(result.rig), 0.0 <= result.analysis.covered_fraction <= 1.0
(3, True)
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from scanrig.errors import InputError
from scanrig.geometry.rig import Rig

from .accuracy import speckle_floor_m
from .analysis import RigAnalysis, analyze_rig
from .candidates import (Candidate, MountingError, candidates_from_positions, candidates_from_rig, check_region,
                         look_at_pose,
                         make_camera, mounting_positions, ring_positions)
from .elements import SurfaceElements, check_mesh, refine_mesh, surface_elements
from .optimize import Selection, select_cameras
from .spec import DesignSpec, default_spec
from .visibility import RayCaster, inside

if TYPE_CHECKING:
    import trimesh

#: Elements the camera search evaluates; a bigger mesh is sampled (area-weighted points), a
#: smaller one has its faces split up to this many. 20 000 elements put the covered fraction
#: within ~0.4 % (binomial 1-sigma at 50 %) of the full mesh's.
SEARCH_ELEMENTS = 20_000


class TargetError(InputError):
    """The accuracy target cannot be reached with the given optics (below the speckle limit)."""

    def __init__(self, message: str, best_achievable_m: float):
        super().__init__(message)
        self.best_achievable_m = best_achievable_m


@dataclass(frozen=True)
class Design:
    """A designed (or analysed) rig with its predictions.

    Attributes
    ----------
    rig : Rig
        The chosen cameras, named ``cam0 ...`` in order of selection.
    spec : DesignSpec
        The complete spec used (defaults filled in).
    mesh : trimesh.Trimesh
        The mesh analysed: the object's, its faces split if it had fewer than
        :data:`SEARCH_ELEMENTS` (:func:`~scanrig.design.elements.refine_mesh`).
    analysis : RigAnalysis
        Predictions on every face of ``mesh``.
    selection : Selection or None
        The search (marginal gains); ``None`` when an explicit rig was analysed.
    ring : RigAnalysis or None
        The symmetric ring of the same cameras, for comparison.
    ring_rig : Rig or None
    """

    rig: Rig
    spec: DesignSpec
    mesh: trimesh.Trimesh
    analysis: RigAnalysis
    selection: Selection | None = None
    ring: RigAnalysis | None = None
    ring_rig: Rig | None = None


def prepare(mesh, spec: DesignSpec, mesh_name: str = "mesh") -> DesignSpec:
    """Check the mesh and complete the spec from its bounding sphere.

    Raises
    ------
    MeshError, MountingError
    """
    check_mesh(mesh, mesh_name)
    center, radius = _bounding_sphere(mesh)
    spec = default_spec(spec, center, radius)
    check_region(spec.mounting, center, radius)
    return spec


def design_rig(mesh, n_cameras: int, spec: DesignSpec, rng: np.random.Generator, mesh_name: str = "mesh",
               allow_open: bool = False, compare_ring: bool = True, search_elements: int = SEARCH_ELEMENTS,
               occluders=(), progress: Callable[[int, int], None] | None = None) -> Design:
    """Choose ``n_cameras`` camera poses and lenses for an object, and predict what they achieve.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The object, metres, world frame.
    n_cameras : int
        Cameras to place (at least ``spec.target.min_views``).
    spec : DesignSpec
        Cameras, mounting region, laser, target; ``None`` fields are derived from the object.
    rng : numpy.random.Generator
        Samples the surface of meshes bigger than ``search_elements`` faces.
    mesh_name : str
        Names the mesh in messages.
    allow_open : bool
        Accept a mesh whose back faces candidate cameras see (a sheet or a partial scan, taken as
        one-sided); otherwise that raises :class:`MeshError`.
    compare_ring : bool
        Also analyse a symmetric ring of the same cameras in the middle of the region.
    search_elements : int
        Elements the search evaluates.
    occluders : sequence of trimesh.Trimesh
        Other surfaces that block views but need no coverage (a floor, fixtures).
    progress : callable, optional
        ``progress(done, total)`` over the candidates.

    Returns
    -------
    Design

    Raises
    ------
    MeshError
        The mesh cannot be used: empty, inverted, or (unless ``allow_open``) open where cameras look
        through it.
    MountingError
        The region lies inside the object (its bounding sphere, or every candidate enclosed by
        it) or no candidate sees it.
    TargetError
        The target is below the speckle limit; ``best_achievable_m`` holds the limit.
    """
    if isinstance(n_cameras, bool) or not isinstance(n_cameras, (int, np.integer)) or n_cameras < spec.target.min_views:
        raise InputError(f"cameras must be an integer >= {spec.target.min_views} (target min_views), got {n_cameras!r}")
    spec = prepare(mesh, spec, mesh_name)
    mesh = refine_mesh(mesh, search_elements)
    caster = _caster(mesh, occluders)
    full = surface_elements(mesh)
    search = surface_elements(mesh, search_elements, rng) if len(full) > search_elements else full
    candidates = _outside(_candidates(spec), caster, spec)
    _check_speckle(spec, candidates, search, n_cameras)
    selection = select_cameras(candidates, search, caster, spec, n_cameras, mesh_name=mesh_name,
                               allow_open=allow_open, progress=progress)
    rig = Rig(replace(c.camera, name=f"cam{i}") for i, c in enumerate(selection.candidates))
    ring_rig = ring = None
    if compare_ring:
        ring_rig = ring_rig_for(spec, n_cameras, [c.focal_length_m for c in selection.candidates])
        ring = analyze_rig(ring_rig.cameras, full, caster, spec)
    return Design(rig, spec, mesh, analyze_rig(rig.cameras, full, caster, spec), selection, ring, ring_rig)


def analyze_existing(mesh, rig: Rig, spec: DesignSpec, mesh_name: str = "mesh", occluders=(),
                     search_elements: int = SEARCH_ELEMENTS) -> Design:
    """Predictions for a given rig (no search): coverage, uncertainty, density per face.

    Arguments as for :func:`design_rig`; ``rig`` is the rig to analyse, and a mesh with fewer
    than ``search_elements`` faces is split to about that many, as the design does.
    """
    spec = prepare(mesh, spec, mesh_name)
    mesh = refine_mesh(mesh, search_elements)
    return Design(rig, spec, mesh, analyze_rig(rig.cameras, surface_elements(mesh), _caster(mesh, occluders), spec))


def _caster(mesh, occluders) -> RayCaster:
    import trimesh

    return RayCaster(trimesh.util.concatenate([mesh, *occluders]) if occluders else mesh)


def ring_rig_for(spec: DesignSpec, n_cameras: int, focal_lengths_m: list[float]) -> Rig:
    """The symmetric-ring baseline: ``n_cameras`` evenly spaced in azimuth mid-region, same lenses."""
    positions = ring_positions(spec.mounting, n_cameras)
    return Rig(make_camera(f"ring{i}", spec.camera, f, look_at_pose(position, spec.mounting.look_at, spec.mounting.up))
               for i, (position, f) in enumerate(zip(positions, sorted(focal_lengths_m), strict=True)))


def _candidates(spec: DesignSpec) -> list[Candidate]:
    if spec.mounting.rig is not None:
        from scanrig.io.rig_file import load_rig

        return candidates_from_rig(load_rig(spec.mounting.rig), spec.camera)
    return candidates_from_positions(mounting_positions(spec.mounting), spec.camera, spec.mounting)


def _outside(candidates: list[Candidate], caster: RayCaster, spec: DesignSpec) -> list[Candidate]:
    """The candidates not enclosed by the object (or a closed occluder)."""
    enclosed = inside(np.array([c.camera.center_world for c in candidates]), np.asarray(spec.mounting.look_at), caster)
    if enclosed.all():
        raise MountingError(f"[mounting]: all {len(candidates)} candidate positions lie inside the object; "
                            "move the region (radius_m, height_m, look_at) outside it")
    return [c for c, e in zip(candidates, enclosed, strict=True) if not e]


def _check_speckle(spec: DesignSpec, candidates: list[Candidate], elements: SurfaceElements, n_cameras: int) -> None:
    centers = np.array([c.camera.center_world for c in candidates])
    nearest = min(float(np.min(np.linalg.norm(elements.points - c, axis=1))) for c in centers)
    longest = max(c.focal_length_m for c in candidates)
    floor = speckle_floor_m(replace(spec.camera, focal_lengths_m=(longest,)), spec.laser, n_cameras, nearest)
    if spec.target.sigma_m < floor:
        raise TargetError(
            f"[target] sigma_m {spec.target.sigma_m:.3g} m is below the speckle limit of these optics: the best "
            f"achievable with {n_cameras} cameras is {floor:.3g} m (lambda {spec.laser.wavelength_m:.3g} m, "
            f"f/{spec.camera.f_number:g}, longest lens {longest:.3g} m, nearest "
            f"camera {nearest:.3g} m away, detection noise 0); relax the target, open the aperture, use longer "
            "lenses, mount closer or reduce speckle contrast", floor)


def _bounding_sphere(mesh) -> tuple[np.ndarray, float]:
    """Centre (the bounding-box centre) and radius enclosing every vertex, metres."""
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    center = (vertices.min(axis=0) + vertices.max(axis=0)) / 2.0
    return center, float(np.linalg.norm(vertices - center, axis=1).max())
