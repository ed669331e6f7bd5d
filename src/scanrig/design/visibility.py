"""Which surface elements a camera sees: in the image, facing it, not too oblique, not occluded.

Occlusion is one batch of rays per camera, from the optical centre to every element, cast with
Embree (through ``embreex``; about 0.15 s per million rays on one core, the reference notes'
dependency survey §4). An element is occluded when the first hit along its ray is nearer than the
element itself by more than a small tolerance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scanrig.geometry.camera import Camera

from .elements import SurfaceElements

#: An element counts as hit by its own ray when the first hit is at most this fraction of the
#: mesh's extent before it: Embree works in float32 (relative precision 6e-8) on coordinates
#: scaled to the unit box, so hit distances are good to ~1e-7 of the extent; 1e-5 leaves margin
#: yet still sees an occluder 5 µm in front of an element on a 0.5 m part.
OCCLUSION_TOL = 1e-5

#: Elements facing away by more than this cosine (about 3 degrees past edge-on) count as back
#: faces; nearer edge-on, a silhouette element's own neighbours may not hide it.
BACK_FACE_COS = 0.05


class RayCaster:
    """First-hit distances of rays against a triangle mesh (Embree, float32).

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The object, metres.

    Attributes
    ----------
    extent_m : float
        Largest side of the mesh's bounding box, metres.
    face_normals : (F, 3) float array
        Unit normals of the mesh's faces, world frame.

    Notes
    -----
    As trimesh's own Embree wrapper does, coordinates are shifted and scaled into the unit box
    before they reach Embree, so float32 keeps the same relative precision for any object size.
    trimesh's ``intersects_first`` returns only the face index; the hit distance is needed here
    to tell an element's own hit from a neighbour's at a shared edge.
    """

    def __init__(self, mesh):
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        vertices = np.asarray(mesh.vertices, dtype=np.float64)
        self.face_normals = np.asarray(mesh.face_normals, dtype=np.float64)
        self._origin = vertices.min(axis=0)
        self.extent_m = max(float(np.ptp(vertices, axis=0).max()), np.finfo(float).tiny)
        self._scale = 1.0 / self.extent_m
        self._scene = rtcore_scene.EmbreeScene()
        TriangleMesh(scene=self._scene, vertices=((vertices - self._origin) * self._scale).astype(np.float32),
                     indices=np.asarray(mesh.faces, dtype=np.int32))

    def first_hit(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distance to the first hit along each ray, and the face hit.

        Parameters
        ----------
        origins : (N, 3) float array
            Ray origins, world frame, metres.
        directions : (N, 3) float array
            Unit directions, world frame.

        Returns
        -------
        distance_m : (N,) float array
            Metres; ``inf`` where the ray misses the mesh.
        face : (N,) int array
            Index of the face hit; -1 on a miss.
        """
        scaled = ((origins - self._origin) * self._scale).astype(np.float32)
        result = self._scene.run(scaled, directions.astype(np.float32), output=1)
        face = result["primID"].astype(np.int64)
        distance = result["tfar"].astype(np.float64) / self._scale
        distance[face < 0] = np.inf
        return distance, face


@dataclass(frozen=True)
class View:
    """How one camera sees every element.

    Attributes
    ----------
    seen : (N,) bool array
        In the image, facing the camera within the incidence limit, and not occluded.
    cos_incidence : (N,) float array
        Cosine of the angle between the element's normal and the direction to the camera
        (negative for back faces).
    distance_m : (N,) float array
        Distance from the optical centre to the element, metres.
    direction : (N, 3) float array
        Unit direction from the element to the optical centre, world frame.
    seen_from_behind : (N,) bool array
        In the image, facing away from the camera, yet not occluded: impossible on a closed mesh
        with outward normals (see :func:`~scanrig.design.elements.check_back_faces`).
    """

    seen: np.ndarray
    cos_incidence: np.ndarray
    distance_m: np.ndarray
    direction: np.ndarray
    seen_from_behind: np.ndarray


def view(camera: Camera, elements: SurfaceElements, caster: RayCaster, max_incidence_rad: float) -> View:
    """Visibility of every element from one camera.

    Parameters
    ----------
    camera : Camera
    elements : SurfaceElements
    caster : RayCaster
        Built on the same mesh as ``elements``.
    max_incidence_rad : float
        Views more oblique than this (angle between normal and line of sight) are not counted.

    Returns
    -------
    View
    """
    center = camera.center_world
    to_cam = center - elements.points
    distance = np.linalg.norm(to_cam, axis=1)
    direction = to_cam / distance[:, None]
    cos_incidence = np.einsum("ij,ij->i", direction, elements.normals)
    q = camera.project(elements.points)
    in_image = ((q[:, 0] >= -0.5) & (q[:, 0] <= camera.width - 0.5)
                & (q[:, 1] >= -0.5) & (q[:, 1] <= camera.height - 0.5))       # NaN compares False
    front = in_image & (cos_incidence >= np.cos(max_incidence_rad))
    back = in_image & (cos_incidence < -BACK_FACE_COS)
    unoccluded = np.zeros(len(elements), dtype=bool)
    idx = np.flatnonzero(front | back)
    if idx.size:
        hit, _ = caster.first_hit(np.broadcast_to(center, (idx.size, 3)), -direction[idx])
        unoccluded[idx] = hit >= distance[idx] - OCCLUSION_TOL * caster.extent_m
    return View(front & unoccluded, cos_incidence, distance, direction, back & unoccluded)


def inside(points_world: np.ndarray, target_world: np.ndarray, caster: RayCaster) -> np.ndarray:
    """Which points are enclosed by the mesh: every ray from them first hits a face from behind.

    Rays go towards ``target_world`` and along the six axis directions; a point behind an open
    sheet or looking through a hole has some ray that escapes or meets a front face.

    Parameters
    ----------
    points_world : (N, 3) float array
        Points to test (camera centres), world frame, metres.
    target_world : (3,) float array
        A point one ray aims at (the object's centre).
    caster : RayCaster

    Returns
    -------
    (N,) bool array
    """
    to_target = target_world - points_world
    length = np.linalg.norm(to_target, axis=1, keepdims=True)
    # a point at the target itself: that ray is just another axis ray
    directions = [np.where(length > 0, to_target / np.where(length > 0, length, 1.0), [1.0, 0.0, 0.0])]
    directions += [np.broadcast_to(d, points_world.shape) for d in np.r_[np.eye(3), -np.eye(3)]]
    enclosed = np.ones(len(points_world), dtype=bool)
    for dirs in directions:
        _, face = caster.first_hit(points_world, dirs)
        hit = face >= 0
        back = np.zeros(len(points_world), dtype=bool)
        back[hit] = np.einsum("ij,ij->i", caster.face_normals[face[hit]], dirs[hit]) > 0
        enclosed &= back
    return enclosed
