"""A small synthetic session with results (rig, cloud, surface, mesh, truth) for report and export tests.

The object is a sphere of radius :data:`RADIUS_M`; the cloud is its surface plus Gaussian noise of
:data:`NOISE_M` along the normal and a few gross outliers, as a reconstruction would give.
"""

from pathlib import Path

import numpy as np
import trimesh

from scanrig.geometry import Camera, RigidTransform, Rig
from scanrig.io.atomic import write_bytes_atomic
from scanrig.io.ply import write_ply
from scanrig.io.rig_file import save_rig
from scanrig.reconstruct.points import PointCloud, write_points

RADIUS_M = 0.05
NOISE_M = 1e-4
N_POINTS = 2000
N_OUTLIERS = 20
OUTLIER_OFFSET_M = 0.01
#: The true mesh: an icosphere this fine lies within ~0.01 mm of the sphere (a tenth of NOISE_M).
TRUTH_SUBDIVISIONS = 5


def look_at(center_world: np.ndarray, target_world: np.ndarray) -> RigidTransform:
    """``cam_from_world`` of a camera at ``center_world`` looking at ``target_world``, world z up."""
    z = target_world - center_world
    z = z / np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    return RigidTransform(R, -R @ center_world)


def make_rig(n_cameras: int = 3) -> Rig:
    cams = []
    for i, az in enumerate(np.linspace(0.0, 2 * np.pi, n_cameras, endpoint=False)):
        center = 0.4 * np.array([np.cos(az), np.sin(az), 0.5])
        params = [1500.0, 1500.0, 639.5, 511.5, -0.1, 0.05, 0.0, 0.0, 0.0]
        cams.append(Camera(f"cam{i}", "opencv5", params, 1280, 1024, look_at(center, np.zeros(3))))
    return Rig(cams)


def make_cloud(rng: np.random.Generator) -> PointCloud:
    normals = rng.normal(size=(N_POINTS, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    radius = RADIUS_M + rng.normal(0.0, NOISE_M, N_POINTS)
    radius[:N_OUTLIERS] += OUTLIER_OFFSET_M
    p = normals * radius[:, None]
    return PointCloud(p, np.full(N_POINTS, NOISE_M), np.full(N_POINTS, 3), rng.uniform(0, 0.3, N_POINTS),
                      np.arange(N_POINTS) // 10, np.zeros(N_POINTS))


def make_session(root: Path, rng: np.random.Generator) -> Path:
    """Write rig.toml, points.ply, surface.ply, mesh.ply and truth/meshes/sphere.ply into ``root``."""
    root = Path(root)
    (root / "truth" / "meshes").mkdir(parents=True, exist_ok=True)
    save_rig(make_rig(), root / "rig.toml", metadata={"seed": 7})
    cloud = make_cloud(rng)
    write_points(root / "points.ply", cloud, comments=("seed: 7",))
    # As `scanrig filter` writes it: every input point, flagged; the outliers come first here.
    p = cloud.p_world
    write_ply(root / "surface.ply", {"x": p[:, 0], "y": p[:, 1], "z": p[:, 2],
                                     "inlier": (np.arange(N_POINTS) >= N_OUTLIERS).astype(np.uint8)})
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=RADIUS_M)
    v = np.asarray(sphere.vertices)
    write_ply(root / "mesh.ply", {"x": v[:, 0], "y": v[:, 1], "z": v[:, 2]}, faces=np.asarray(sphere.faces))
    truth = trimesh.creation.icosphere(subdivisions=TRUTH_SUBDIVISIONS, radius=RADIUS_M)
    write_bytes_atomic(root / "truth" / "meshes" / "sphere.ply", truth.export(file_type="ply"))
    return root
