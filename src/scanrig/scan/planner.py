"""The scan planner: a uniform first pass over a region of interest, then adaptive refinement.

Each adaptive pass (``docs/scanning.md``, "Planner"):

1. estimates the surface from the points so far (PCA normals over ``k`` neighbours, oriented
   toward the laser origin that produced each point);
2. proposes candidate locations one target spacing away from every point, in six directions of
   its tangent plane (a random rotation per point, drawn from ``rng``, avoids aliasing with the
   grid of the first pass);
3. keeps the candidates that lie in a gap (no measured point within ``GAP_FRACTION`` of the
   spacing) and that no earlier beam was already aimed at;
4. thins them to one per spacing, largest gap first, and aims a beam at each along its inward
   normal from the best station (:class:`~scanrig.scan.reach.Stations`).

The scan stops when a pass finds no gap (density target reached) or the beam budget is spent.
A plan is a pure function of (points so far, beams and aims so far, ``rng`` state), so a
resumed scan plans exactly what an uninterrupted one would.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from scanrig.errors import InputError
from scanrig.geometry.checks import check_matrix, check_points
from scanrig.scan.coverage import surface_normals, tangent_basis
from scanrig.scan.protocol import Beam
from scanrig.scan.reach import Stations

#: A candidate is a gap when its nearest measured point is at least this fraction of the target
#: spacing away. Candidates sit one spacing from a point, so this only keeps real holes; a square
#: grid coarser than ~1.3 spacings still produces gaps, one finer than ~1.2 does not, which puts
#: the fixed point of the loop below the 1.5x acceptance factor.
GAP_FRACTION = 0.9
#: Candidates within this fraction of the spacing of an earlier aim are not tried again.
TRIED_FRACTION = 0.5
#: Tangent directions probed around each point (hexagonal).
N_DIRECTIONS = 6


@dataclass(frozen=True)
class PlannerConfig:
    """Settings of a scan plan (JSON-serialisable through :meth:`to_dict`).

    Parameters
    ----------
    spacing_m : float
        Target point spacing on the surface, metres.
    roi_min_m, roi_max_m : (3,) float
        Corners of the axis-aligned region of interest, world frame, metres.
    uniform_spacing_m : float, optional
        Grid spacing of the first pass on its aim plane (default: ``spacing_m``).
    max_beams_per_pass : int
        Cap on the beams of one adaptive pass, so that the surface estimate is refreshed often.
    max_passes : int
        Cap on the number of passes, the uniform one included.
    neighbours : int
        Neighbourhood size for normals and density.
    stations_m : list of (3,) float
        Laser stations (see :class:`~scanrig.scan.reach.Stations`); station 0 makes the uniform pass.
    max_incidence_deg : float
        Largest beam-to-normal angle accepted for an adaptive beam.
    """

    spacing_m: float
    roi_min_m: tuple[float, float, float]
    roi_max_m: tuple[float, float, float]
    stations_m: tuple[tuple[float, float, float], ...]
    uniform_spacing_m: float | None = None
    max_beams_per_pass: int = 200
    max_passes: int = 10
    neighbours: int = 10
    max_incidence_deg: float = 75.0
    stripe: bool = field(default=False)

    def __post_init__(self):
        if not self.spacing_m > 0:
            raise InputError(f"spacing_m must be positive, got {self.spacing_m}")
        lo = check_matrix(self.roi_min_m, (3,), "roi_min_m")
        hi = check_matrix(self.roi_max_m, (3,), "roi_max_m")
        if np.any(hi <= lo):
            raise InputError(f"roi_max_m must exceed roi_min_m on every axis, got {lo.tolist()} and {hi.tolist()}")
        object.__setattr__(self, "roi_min_m", tuple(lo.tolist()))
        object.__setattr__(self, "roi_max_m", tuple(hi.tolist()))
        stations = check_points(self.stations_m, 3, "stations_m")
        object.__setattr__(self, "stations_m", tuple(tuple(s) for s in stations.tolist()))
        if self.uniform_spacing_m is not None and not self.uniform_spacing_m > 0:
            raise InputError(f"uniform_spacing_m must be positive, got {self.uniform_spacing_m}")
        for name in ("max_beams_per_pass", "max_passes", "neighbours"):
            if int(getattr(self, name)) < 1:
                raise InputError(f"{name} must be a positive integer, got {getattr(self, name)!r}")

    def to_dict(self) -> dict:
        """Plain dict (lists, floats) for the manifest."""
        d = asdict(self)
        d["roi_min_m"], d["roi_max_m"] = list(self.roi_min_m), list(self.roi_max_m)
        d["stations_m"] = [list(s) for s in self.stations_m]
        return d

    @classmethod
    def from_dict(cls, d: dict) -> PlannerConfig:
        """Inverse of :meth:`to_dict`."""
        return cls(**{**d, "stations_m": tuple(map(tuple, d["stations_m"]))})

    @property
    def stations(self) -> Stations:
        return Stations(np.array(self.stations_m), self.max_incidence_deg)


@dataclass(frozen=True)
class History:
    """What the planner knows: every point measured so far and every beam aimed so far.

    Parameters
    ----------
    points_m : (N, 3) float array
        Measured points (finite), world frame, metres.
    point_beam : (N,) int array
        Index (into ``beams``) of the beam that produced each point.
    beams : list of Beam
        Every beam planned so far, in order.
    aims_m : (len(beams), 3) float array
        Aim point of each beam, metres.
    """

    points_m: np.ndarray
    point_beam: np.ndarray
    beams: list[Beam]
    aims_m: np.ndarray

    @classmethod
    def empty(cls) -> History:
        return cls(np.empty((0, 3)), np.empty(0, dtype=np.int64), [], np.empty((0, 3)))


@dataclass(frozen=True)
class Plan:
    """Beams of one pass and the points they were aimed at (``aims_m``: (n, 3), metres).

    ``reason`` says why a plan is empty (the scan's stopping reason).
    """

    beams: list[Beam]
    aims_m: np.ndarray
    reason: str = ""


def plan_pass(config: PlannerConfig, pass_number: int, history: History, rng: np.random.Generator,
              max_beams: int) -> Plan:
    """Plan one pass: the uniform grid for pass 0, adaptive refinement afterwards.

    The uniform grid is coarsened (never truncated) when it would take more than half of the
    remaining budget: the other half is kept for the adaptive passes.

    Parameters
    ----------
    config : PlannerConfig
    pass_number : int
        0 for the uniform pass.
    history : History
        Points, beams and aims so far.
    rng : numpy.random.Generator
        Consumed by adaptive passes only.
    max_beams : int
        Remaining beam budget; the plan never exceeds it.

    Returns
    -------
    Plan
        Empty, with its ``reason``, when nothing is left to do.
    """
    if max_beams <= 0:
        return Plan([], np.empty((0, 3)), "beam budget spent")
    if pass_number >= config.max_passes:
        return Plan([], np.empty((0, 3)), "pass limit reached")
    if pass_number == 0:
        grid_m = config.uniform_spacing_m or config.spacing_m
        aims = uniform_aims(config, grid_m)
        cap = max(1, max_beams // 2)
        while len(aims) > cap:                        # coarsen the grid until half the budget holds it
            grid_m *= max(1.05, np.sqrt(len(aims) / cap))
            aims = uniform_aims(config, grid_m)
        return Plan(_with_fan(config, config.stations.beams_toward(aims, 0), None), aims)
    return adaptive_plan(config, history, rng, min(max_beams, config.max_beams_per_pass))


def uniform_aims(config: PlannerConfig, grid_spacing_m: float) -> np.ndarray:
    """Aim points of a regular grid over the region of interest, seen from station 0.

    The grid lies on the plane through the ROI's centre perpendicular to the line of sight from
    station 0, and covers the central projection of the ROI box onto that plane.

    Returns
    -------
    (M, 3) float array
        Aim points, world frame, metres, in row-major (boustrophedon-free) grid order.
    """
    lo, hi = np.array(config.roi_min_m), np.array(config.roi_max_m)
    station = np.array(config.stations_m[0])
    centre = (lo + hi) / 2
    view = centre - station
    view /= np.linalg.norm(view)
    e1, e2 = (t[0] for t in tangent_basis(view[None]))
    corners = np.array(np.meshgrid(*zip(lo, hi), indexing="ij")).reshape(3, -1).T
    rays = corners - station
    on_plane = station + rays * ((centre - station) @ view / (rays @ view))[:, None]
    a, b = (on_plane - centre) @ e1, (on_plane - centre) @ e2
    ga = _grid_axis(a.min(), a.max(), grid_spacing_m)
    gb = _grid_axis(b.min(), b.max(), grid_spacing_m)
    A, B = np.meshgrid(ga, gb, indexing="ij")
    return centre + A.reshape(-1, 1) * e1 + B.reshape(-1, 1) * e2


def adaptive_plan(config: PlannerConfig, history: History, rng: np.random.Generator, max_beams: int) -> Plan:
    """Beams perpendicular to the under-sampled patches of the surface measured so far.

    See the module docstring for the steps. Returns an empty plan when there are too few points
    to estimate a surface or no gap is left.
    """
    points = history.points_m
    s = config.spacing_m
    if len(points) <= config.neighbours:
        return Plan([], np.empty((0, 3)), f"too few points ({len(points)}) to estimate the surface: raise the "
                                          f"beam budget or move the region of interest onto the object")
    origins = np.array([b.origin for b in history.beams])[history.point_beam]
    normals, _ = surface_normals(points, config.neighbours, toward_m=origins)
    t1, t2 = tangent_basis(normals)
    theta = rng.uniform(0.0, 2 * np.pi, len(points))[:, None] + np.arange(N_DIRECTIONS) * (2 * np.pi / N_DIRECTIONS)
    cand = points[:, None, :] + s * (np.cos(theta)[..., None] * t1[:, None] + np.sin(theta)[..., None] * t2[:, None])
    cand = cand.reshape(-1, 3)
    cand_normals = np.repeat(normals, N_DIRECTIONS, axis=0)
    gap, _ = cKDTree(points).query(cand)
    keep = (gap >= GAP_FRACTION * s) & _inside(cand, config)
    if len(history.aims_m):
        tried, _ = cKDTree(history.aims_m).query(cand)
        keep &= tried >= TRIED_FRACTION * s
    cand, cand_normals, gap = cand[keep], cand_normals[keep], gap[keep]
    station, _ = config.stations.best_station(cand, cand_normals)
    ok = station >= 0
    cand, cand_normals, gap, station = cand[ok], cand_normals[ok], gap[ok], station[ok]
    chosen = _thin(cand, gap, GAP_FRACTION * s, max_beams)
    if len(chosen) == 0:
        return Plan([], np.empty((0, 3)), "density target reached")
    aims = cand[chosen]
    origins = np.array(config.stations_m)[station[chosen]]
    dirs = aims - origins
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    beams = [Beam(o, d) for o, d in zip(origins, dirs)]
    return Plan(_with_fan(config, beams, cand_normals[chosen]), aims)


def _thin(cand: np.ndarray, priority: np.ndarray, radius: float, limit: int) -> np.ndarray:
    """Greedy non-maximum suppression: indices of candidates at least ``radius`` apart, best first.

    Greedy selection is sequential by nature (each pick removes its neighbours), so it is a Python
    loop; it runs once per pass over a few thousand candidates, with the neighbour lists from a
    k-d tree.
    """
    order = np.lexsort((np.arange(len(cand)), -priority))      # ties broken by index: deterministic
    neighbours = cKDTree(cand).query_ball_point(cand, radius)
    removed = np.zeros(len(cand), dtype=bool)
    chosen = []
    for i in order:
        if removed[i]:
            continue
        chosen.append(i)
        if len(chosen) == limit:
            break
        removed[neighbours[i]] = True
    return np.array(chosen, dtype=np.int64)


def _inside(p: np.ndarray, config: PlannerConfig) -> np.ndarray:
    return np.all((p >= config.roi_min_m) & (p <= config.roi_max_m), axis=1)


def _grid_axis(lo: float, hi: float, step: float) -> np.ndarray:
    n = int(np.floor((hi - lo) / step)) + 1
    return (lo + hi) / 2 + (np.arange(n) - (n - 1) / 2) * step


def _with_fan(config: PlannerConfig, beams: list[Beam], normals: np.ndarray | None) -> list[Beam]:
    """Stripe lasers: give each beam a fan axis perpendicular to it (along a tangent of the patch)."""
    if not config.stripe:
        return beams
    out = []
    for i, b in enumerate(beams):
        ref = np.cross(b.direction, normals[i]) if normals is not None else np.zeros(3)
        if np.linalg.norm(ref) < 1e-6:
            ref = np.cross(b.direction, [0.0, 0.0, 1.0] if abs(b.direction[2]) < 0.9 else [1.0, 0.0, 0.0])
        out.append(Beam(b.origin, b.direction, ref / np.linalg.norm(ref)))
    return out
