"""Random cameras for geometry tests: every model, strong distortion, points over the view."""

import numpy as np

from scanrig.geometry import Camera, RigidTransform
from scanrig.geometry.distortion import MODEL_COEFFICIENTS

MODELS = [m for m in MODEL_COEFFICIENTS if m != "pinhole"]


def random_camera(rng: np.random.Generator, model: str, k1_max: float = 0.5) -> Camera:
    """A camera with realistic intrinsics, |k1| up to ``k1_max`` and random small other terms."""
    n = len(MODEL_COEFFICIENTS[model])
    d = rng.normal(0.0, 0.02, n)
    d[0] = rng.uniform(-k1_max, k1_max)
    if n >= 8:
        d[5:8] = rng.normal(0.0, 0.01, 3)
    if n == 12:
        d[8:] = rng.normal(0.0, 0.002, 4)
    f = rng.uniform(500.0, 2500.0)
    params = np.r_[f, f * rng.uniform(0.95, 1.05), rng.uniform(600, 680), rng.uniform(480, 540), d]
    pose = RigidTransform.from_rvec_tvec(rng.normal(0.0, 0.6, 3), rng.normal(0.0, 0.5, 3))
    return Camera("cam", model, params, 1280, 1024, pose)


def points_in_view(rng: np.random.Generator, cam: Camera, n: int, half_fov: float = 0.5) -> np.ndarray:
    """World points whose normalised coordinates lie in ``[-half_fov, half_fov]²``, depth 0.3–5 m."""
    xy = rng.uniform(-half_fov, half_fov, (n, 2))
    z = rng.uniform(0.3, 5.0, n)
    p_cam = np.c_[xy * z[:, None], z]
    return cam.cam_from_world.inverse().apply(p_cam)
