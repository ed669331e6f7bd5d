"""Small objects and specs shared by the design tests."""

import numpy as np
import trimesh

from scanrig.design.spec import CameraSpec, DesignSpec, LaserSpec, MountingSpec, TargetSpec


def sheet(size_m: float = 0.2, n: int = 20) -> trimesh.Trimesh:
    """A square grid of ``2 n²`` triangles in the plane z = 0, normals +z (an open mesh)."""
    x = np.linspace(-size_m / 2, size_m / 2, n + 1)
    xx, yy = np.meshgrid(x, x)
    vertices = np.c_[xx.ravel(), yy.ravel(), np.zeros(xx.size)]
    i = np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]
    a, b, c, d = i.ravel(), i.ravel() + 1, i.ravel() + n + 1, i.ravel() + n + 2
    faces = np.r_[np.c_[a, b, d], np.c_[a, d, c]]
    return trimesh.Trimesh(vertices, faces, process=False)


def small_spec(**target) -> DesignSpec:
    """A cylinder region 0.5–0.7 m around a ~0.1 m object, one 12 mm lens, f/4, 0.3 px detection."""
    return DesignSpec(
        camera=CameraSpec(width_px=1280, height_px=1024, pixel_pitch_m=4.8e-6, focal_lengths_m=(0.012,)),
        mounting=MountingSpec(radius_m=(0.5, 0.7), height_m=(0.1, 0.5), look_at=(0.0, 0.0, 0.05), n_candidates=24),
        laser=LaserSpec(sigma_px=0.3, step_m=1e-3),
        target=TargetSpec(**{"sigma_m": 2e-4, **target}),
    )
