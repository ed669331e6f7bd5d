"""A stand-in rig for the scan tests: a spot laser on a tilted roof, seen by three small cameras.

The scene is analytic (two planes meeting at a ridge, one of them steep), each camera image is a
Gaussian spot at the projection of the hit point plus noise; the real spot processing
(``SpotProcessor``: detection, then triangulation) turns the frames into points. The noise of a frame is drawn from a
generator seeded by the scene seed and the beam itself, so a re-captured frame is bit-identical:
a resumed scan must therefore give exactly the points of an uninterrupted one.
"""

from __future__ import annotations

import hashlib
import time

import numpy as np

from scanrig.geometry import Camera, Rig, RigidTransform
from scanrig.scan.planner import PlannerConfig

WIDTH, HEIGHT = 80, 64
SPOT_SIGMA_PX = 1.2
SPOT_PEAK_DN = 200.0
NOISE_DN = 2.0
#: Ridge along y at x = 0; the roof rises 1:1 (45 degrees) for x < 0 and 3:1 (72 degrees) for x > 0.
SLOPE_LEFT, SLOPE_RIGHT, RIDGE_Z = 1.0, 3.0, 0.03


def look_at(name: str, centre, target=(0.0, 0.0, 0.015), f_px=70.0) -> Camera:
    centre, target = np.asarray(centre, float), np.asarray(target, float)
    z = target - centre
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return Camera(name, "pinhole", np.array([f_px, f_px, (WIDTH - 1) / 2, (HEIGHT - 1) / 2]), WIDTH, HEIGHT,
                  RigidTransform(R, -R @ centre))


def make_rig() -> Rig:
    return Rig([look_at("cam0", (0.25, -0.1, 0.2)), look_at("cam1", (-0.25, -0.1, 0.2)),
                look_at("cam2", (0.05, 0.25, 0.2))])


def planner_config(spacing_m=0.008, **kw) -> PlannerConfig:
    stations = [(0.0, 0.0, 0.3), (0.3, 0.0, 0.12), (-0.3, 0.0, 0.15)]
    return PlannerConfig(spacing_m=spacing_m, roi_min_m=(-0.04, -0.03, -0.1), roi_max_m=(0.04, 0.03, 0.05),
                         stations_m=stations, **kw)


def surface_z(x):
    """Height of the roof above x (metres)."""
    return RIDGE_Z - np.where(x < 0, SLOPE_LEFT * -x, SLOPE_RIGHT * x)


def distance_to_roof(p):
    """Perpendicular distance of points ``(N, 3)`` to the nearer of the two roof planes, metres."""
    left = np.abs(p[:, 2] - RIDGE_Z - SLOPE_LEFT * p[:, 0]) / np.hypot(1.0, SLOPE_LEFT)
    right = np.abs(p[:, 2] - RIDGE_Z + SLOPE_RIGHT * p[:, 0]) / np.hypot(1.0, SLOPE_RIGHT)
    return np.minimum(left, right)


def hit(origin, direction):
    """First intersection of a ray with the roof (two planes), by bisection on the height gap."""
    t_lo, t_hi = 0.0, 2.0
    gap = lambda t: (origin[2] + t * direction[2]) - surface_z(origin[0] + t * direction[0])  # noqa: E731
    if gap(t_hi) > 0:
        return None
    for _ in range(80):                 # 2 m / 2**80: exact to float precision
        t_mid = (t_lo + t_hi) / 2
        if gap(t_mid) > 0:
            t_lo = t_mid
        else:
            t_hi = t_mid
    return origin + t_hi * direction


class FakeRig:
    """Cameras and positioner in one object, with failure injection for the bad-input tests."""

    def __init__(self, seed=0, delay_s=0.0, fail_move_at=None, camera_dies_at=None, hang=False):
        self.rig = make_rig()
        self.names = self.rig.names
        self.seed, self.delay_s = seed, delay_s
        self.fail_move_at, self.camera_dies_at, self.hang = fail_move_at, camera_dies_at, hang
        self.beam, self.n_moves, self.n_grabs, self.laser = None, 0, 0, False

    def move_to(self, beam):
        if self.fail_move_at is not None and self.n_moves >= self.fail_move_at:
            raise RuntimeError("error:9 (G-code lock)")
        self.n_moves += 1
        self.beam = beam
        time.sleep(self.delay_s)

    def set_laser(self, on):
        self.laser = bool(on)

    def grab(self):
        if self.camera_dies_at is not None and self.n_grabs >= self.camera_dies_at:
            if self.hang:
                time.sleep(60)
            return {n: None for n in self.names} | {self.names[0]: self._image(self.rig.cameras[0], None)}
        self.n_grabs += 1
        key = hashlib.sha256(b"dark" if self.beam is None else np.asarray(self.beam.as_row()).tobytes()).digest()
        rng = np.random.default_rng([self.seed, int.from_bytes(key[:8], "little")])
        p = hit(self.beam.origin, self.beam.direction) if self.laser else None
        return {cam.name: self._image(cam, p, rng) for cam in self.rig.cameras}

    def _image(self, cam, p, rng=None):
        rng = rng or np.random.default_rng(0)
        img = rng.normal(20.0, NOISE_DN, (HEIGHT, WIDTH))
        if p is not None:
            q = cam.project(p[None])[0]
            if np.all(np.isfinite(q)):
                v, u = np.mgrid[0:HEIGHT, 0:WIDTH]
                img += SPOT_PEAK_DN * np.exp(-((u - q[0]) ** 2 + (v - q[1]) ** 2) / (2 * SPOT_SIGMA_PX**2))
        return np.clip(np.rint(img), 0, 255).astype(np.uint8)
