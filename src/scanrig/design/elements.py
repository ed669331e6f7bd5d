"""Surface elements of the object (the unit of coverage) and the mesh checks that visibility needs.

An element is a small piece of the surface: a face of the mesh, or for big meshes an
area-weighted random point on it. Each carries a position, an outward unit normal and the area it
stands for, so that coverage is a fraction of the surface area, not of the face count.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scanrig.errors import InputError


class MeshError(InputError):
    """The object mesh cannot be used as given (open where it is seen, inverted, degenerate)."""


@dataclass(frozen=True)
class SurfaceElements:
    """Pieces of the object's surface.

    Attributes
    ----------
    points : (N, 3) float array
        Element positions, world frame, metres.
    normals : (N, 3) float array
        Outward unit normals, world frame.
    areas : (N,) float array
        Surface area each element stands for, m²; they sum to the mesh area.
    face_index : (N,) int array
        The mesh face each element lies on.
    """

    points: np.ndarray
    normals: np.ndarray
    areas: np.ndarray
    face_index: np.ndarray

    def __len__(self) -> int:
        return self.points.shape[0]

    @property
    def total_area(self) -> float:
        """Surface area of the object, m²."""
        return float(self.areas.sum())


def check_mesh(mesh, name: str = "mesh") -> None:
    """Reject a mesh that visibility cannot use: empty, or closed with its normals pointing inwards.

    An open mesh (a sheet, a scan, a scene with a floor) is accepted here: its openings matter
    only where a camera looks through them, which :func:`check_back_faces` tests once the
    candidate cameras are known.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The object, metres, world frame.
    name : str
        How the mesh is named in messages (its file name).

    Raises
    ------
    MeshError
        No face with area; or watertight with negative volume (normals inwards).
    """
    if len(mesh.faces) == 0 or mesh.area <= 0:
        raise MeshError(f"{name}: the mesh has no faces with area")
    if mesh.is_watertight and mesh.volume < 0:
        raise MeshError(f"{name}: the normals point inwards (negative volume); invert the mesh "
                        "(mesh.invert()) before designing")


def check_back_faces(elements: SurfaceElements, seen_from_behind: np.ndarray, name: str = "mesh",
                     max_fraction: float = 1e-3) -> None:
    """Reject a mesh whose back faces some camera can see.

    On a closed mesh with outward normals a back face is always hidden behind the front of the
    object, so a back face in plain view means the camera looks through a hole or an open
    border, or at a sheet from its back, or the normals point inwards there: the visibility of
    that part of the surface is unreliable.

    Parameters
    ----------
    elements : SurfaceElements
    seen_from_behind : (N,) bool array
        Elements some candidate camera sees from behind (:attr:`View.seen_from_behind`).
    name : str
        The mesh, for the message.
    max_fraction : float
        Area fraction tolerated (grazing views along silhouettes, round-off).

    Raises
    ------
    MeshError
        Naming the area fraction and where it lies.
    """
    area = elements.areas[seen_from_behind].sum()
    if area > max_fraction * elements.total_area:
        p = elements.points[seen_from_behind]
        raise MeshError(
            f"{name}: {100 * area / elements.total_area:.1f} % of the surface (between "
            f"{np.round(p.min(axis=0), 4).tolist()} and {np.round(p.max(axis=0), 4).tolist()} m) is seen from "
            "behind by candidate cameras: the mesh is open there (holes, missing faces) or its normals point "
            "inwards. Close it (trimesh.repair.fill_holes), fix the normals (trimesh.repair.fix_normals), "
            "keep the cameras on the side the normals face, or, for a one-sided surface (a sheet, a partial "
            "scan), allow an open mesh (--allow-open) so that views from behind just do not count")


def refine_mesh(mesh, min_faces: int):
    """A copy of ``mesh`` with faces split until it has about ``min_faces`` or more.

    Coverage is decided per element, so a mesh of a few large faces (a box has 12) would be seen
    all or nothing per face; splitting its faces gives maps with a resolution of about
    ``sqrt(8 area / min_faces)``. Meshes that already have ``min_faces`` faces are returned as
    they are. The split copy may have T-junctions (not watertight); visibility does not need more.

    Parameters
    ----------
    mesh : trimesh.Trimesh
    min_faces : int

    Returns
    -------
    trimesh.Trimesh
    """
    import trimesh

    if len(mesh.faces) >= min_faces:
        return mesh
    max_edge = float(np.sqrt(8.0 * mesh.area / min_faces))
    vertices, faces = mesh.vertices, mesh.faces
    for _ in range(3):  # the face count of a split at a given edge length depends on the shapes
        vertices, faces = trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, max_edge=max_edge, max_iter=30)
        if len(faces) <= 2 * min_faces:
            break
        max_edge *= float(np.sqrt(len(faces) / min_faces))
    return trimesh.Trimesh(vertices, faces, process=False)


def surface_elements(mesh, max_elements: int | None = None, rng: np.random.Generator | None = None
                     ) -> SurfaceElements:
    """Elements covering the mesh: its faces, or area-weighted random points for big meshes.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The object, metres, world frame, outward normals.
    max_elements : int, optional
        If the mesh has more faces than this, draw this many points instead, each face chosen
        with probability proportional to its area and the point uniform on it.
    rng : numpy.random.Generator, optional
        Needed only when sampling.

    Returns
    -------
    SurfaceElements
    """
    areas = np.asarray(mesh.area_faces, dtype=np.float64)
    normals = np.asarray(mesh.face_normals, dtype=np.float64)
    n_faces = len(areas)
    if max_elements is None or n_faces <= max_elements:
        return SurfaceElements(np.asarray(mesh.triangles_center, dtype=np.float64), normals, areas,
                               np.arange(n_faces))
    if rng is None:
        raise InputError(f"rng is needed to sample {max_elements} elements from {n_faces} faces")
    face = rng.choice(n_faces, size=max_elements, p=areas / areas.sum())
    corners = np.asarray(mesh.triangles, dtype=np.float64)[face]            # (M, 3, 3)
    r1, r2 = rng.random(max_elements), rng.random(max_elements)
    s = np.sqrt(r1)
    weights = np.stack([1.0 - s, s * (1.0 - r2), s * r2], axis=1)        # uniform on a triangle
    points = np.einsum("mk,mkj->mj", weights, corners)
    return SurfaceElements(points, normals[face], np.full(max_elements, areas.sum() / max_elements), face)
