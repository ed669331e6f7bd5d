"""A geometric stand-in for the measuring chain, to test and benchmark the planner at full speed.

A beam's point is its first hit on the scene (the simulator's Embree ray caster), kept only when
at least two cameras see it unoccluded, plus isotropic Gaussian noise. No images are rendered:
the planner's job is *where* to put beams, and this answers that question exactly.

The scene is a truncated pyramid with steep (72 degree) faces on a floor, scanned from a station
above it (the uniform pass) and four side stations.
"""

from __future__ import annotations

import numpy as np
import trimesh

from scanrig.scan.planner import History, PlannerConfig, plan_pass, uniform_aims
from scanrig.sim.raycast import RayCaster

NOISE_M = 1e-4
#: Distance a shadow ray starts off the surface, metres (well above float64 round-off of a hit).
SHADOW_EPS_M = 1e-6
BASE_M, TOP_M, HEIGHT_M = 0.10, 0.04, 0.09
CAMERAS_M = np.array([[0.4 * np.cos(a), 0.4 * np.sin(a), 0.35] for a in np.radians([45, 135, 225, 315])])


def frustum() -> trimesh.Trimesh:
    b, t, h = BASE_M / 2, TOP_M / 2, HEIGHT_M
    corners = [[-b, -b, 0], [b, -b, 0], [b, b, 0], [-b, b, 0], [-t, -t, h], [t, -t, h], [t, t, h], [-t, t, h]]
    return trimesh.convex.convex_hull(np.array(corners, dtype=float))


def floor() -> trimesh.Trimesh:
    return trimesh.Trimesh([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], [[0, 1, 2], [0, 2, 3]])


def planner_config(spacing_m=0.004, **kw) -> PlannerConfig:
    stations = [(0.0, 0.0, 0.6)] + [(0.45 * np.cos(a), 0.45 * np.sin(a), 0.12) for a in np.radians([0, 90, 180, 270])]
    return PlannerConfig(spacing_m=spacing_m, roi_min_m=(-0.06, -0.06, 0.002), roi_max_m=(0.06, 0.06, 0.1),
                         stations_m=stations, **kw)


class GeometricRig:
    """Beams in, measured points out (NaN where the spot is missed or seen by fewer than 2 cameras)."""

    def __init__(self):
        self.mesh = frustum()
        self.caster = RayCaster([self.mesh, floor()])

    def seen_by(self, p: np.ndarray) -> np.ndarray:
        """Number of cameras with a clear line of sight to each point, ``(N,)``."""
        count = np.zeros(len(p), dtype=int)
        for c in CAMERAS_M:
            to_cam = c - p
            dist = np.linalg.norm(to_cam, axis=1)
            d = to_cam / dist[:, None]
            count += ~self.caster.occluded(p + SHADOW_EPS_M * d, d, dist - 2 * SHADOW_EPS_M)
        return count

    def measure(self, beams, rng: np.random.Generator) -> np.ndarray:
        origins = np.array([b.origin for b in beams])
        dirs = np.array([b.direction for b in beams])
        hits = self.caster.cast(origins, dirs)
        p = hits.point.copy()
        p[self.seen_by(np.nan_to_num(p)) < 2] = np.nan
        return p + rng.normal(0.0, NOISE_M, p.shape)

    def visible_surface(self, config: PlannerConfig, n: int, rng: np.random.Generator):
        """Samples of the pyramid's surface inside the ROI that 2 cameras and station 0 see.

        Returns
        -------
        samples : (M, 3) float array
            Surface points, metres.
        normals : (M, 3) float array
            Outward unit normals of their faces.
        """
        samples, face = trimesh.sample.sample_surface_even(self.mesh, n, seed=int(rng.integers(2**31)))
        normals = self.mesh.face_normals[face]
        inside = np.all((samples >= config.roi_min_m) & (samples <= config.roi_max_m), axis=1)
        samples, normals = samples[inside], normals[inside]
        station = np.array(config.stations_m[0])
        to_station = station - samples
        dist = np.linalg.norm(to_station, axis=1)
        d = to_station / dist[:, None]
        reachable = ~self.caster.occluded(samples + SHADOW_EPS_M * d, d, dist - 2 * SHADOW_EPS_M)
        keep = reachable & (self.seen_by(samples) >= 2)
        return samples[keep], normals[keep]


def adaptive_scan(rig: GeometricRig, config: PlannerConfig, budget: int, rng: np.random.Generator):
    """Run the planner loop against the geometric rig; returns (points (N, 3), beams per pass)."""
    history, per_pass = History.empty(), []
    for number in range(config.max_passes):
        plan = plan_pass(config, number, history, rng, budget - len(history.beams))
        if not plan.beams:
            break
        p = rig.measure(plan.beams, rng)
        ok = np.all(np.isfinite(p), axis=1)
        history = History(np.vstack([history.points_m, p[ok]]),
                          np.concatenate([history.point_beam, len(history.beams) + np.flatnonzero(ok)]),
                          history.beams + plan.beams, np.vstack([history.aims_m, plan.aims_m]))
        per_pass.append(len(plan.beams))
    return history.points_m, per_pass


def uniform_scan(rig: GeometricRig, config: PlannerConfig, grid_spacing_m: float, rng: np.random.Generator):
    """A uniform grid from station 0 only; returns (points (N, 3), number of beams)."""
    beams = config.stations.beams_toward(uniform_aims(config, grid_spacing_m), 0)
    p = rig.measure(beams, rng)
    return p[np.all(np.isfinite(p), axis=1)], len(beams)
