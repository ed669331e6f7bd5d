"""The laser: Gaussian beams and light sheets, their traces on the scene, and secondary reflections.

Physical model
--------------
* **Spot**: a Gaussian beam of power ``P``; at distance ``z`` along its axis its 1/e² radius is
  ``w(z) = w0 sqrt(1 + ((z - z_focus) / z_R)²)`` with Rayleigh range ``z_R = pi w0² / (M² lambda)``;
  the irradiance across the beam is ``2 P / (pi w²) exp(-2 rho² / w²)`` (``rho`` = distance from
  the axis).
* **Stripe**: a plane of light fanned uniformly over ``±fan_half_angle`` about its central
  direction; across the plane the profile is Gaussian with the same ``w(r)`` law (``r`` = distance
  from the head); along it the power per radian is ``P / (2 half_angle)``, spreading as ``1/r``.
* A surface with unit normal ``n`` receives ``E = I * cos(incidence)``; points that cannot see
  the source along the light's path are shadowed (exact, by casting a ray).
* **Secondary reflections**: where the beam (or a fan sample of the sheet) hits a shiny
  material, a fraction ``specular`` of its power is reflected about the shading normal as a new
  Gaussian beamlet that starts at the hit with the footprint's radius and diverges with the
  lobe's 1/e² half-angle ``2 * roughness_rad``; where it lands is a secondary trace. One bounce
  only.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from scanrig.errors import InputError
from scanrig.sim.beamlet_groups import merge_overlapping

#: Offset of secondary ray origins off the surface, metres (well above float32 hit noise).
SURFACE_EPS_M = 1e-5
#: Footprint extent used for render windows, in 1/e² radii (exp(-2·3²) ≈ 1.5e-8 of the peak).
FOOTPRINT_RADII = 3.0
#: Smallest cosine of incidence used to bound footprint elongation at grazing incidence.
MIN_COS_FOOTPRINT = 0.1
#: Beamlet sets up to this size are evaluated densely; larger ones only near their landings.
_MAX_DENSE_BEAMS = 8
#: Ratio of the largest to the smallest reach of a class of beamlets (GaussianBeams._pairs).
_REACH_CLASS_RATIO = 1.25
#: Points per block in GaussianBeams.evaluate and may_light (their (point, beam) scratch arrays stay in the CPU cache).
_EVAL_BLOCK = 8192
#: Fan samples cast per stripe frame (render windows, secondary beamlets) and written to truth.
N_FAN_SAMPLES = 2048
N_FAN_TRUTH = 512


@dataclass(frozen=True)
class BeamPose:
    """Where the positioner points the laser (world frame, metres); duck-types ``scanrig.scan.Beam``.

    Parameters
    ----------
    origin : (3,) float
        Exit point of the beam (spot) or apex of the fan (stripe).
    direction : (3,) float
        Unit central direction.
    fan_axis : (3,) float or None
        Stripe only: unit vector ⟂ direction spanning the light plane.
    """

    origin: np.ndarray
    direction: np.ndarray
    fan_axis: np.ndarray | None = None

    @classmethod
    def from_any(cls, beam) -> BeamPose:
        """Normalise any object with ``origin``, ``direction`` and optional ``fan_axis``."""
        try:
            origin = np.asarray(beam.origin, dtype=np.float64).reshape(3)
            direction = np.asarray(beam.direction, dtype=np.float64).reshape(3)
            fan = getattr(beam, "fan_axis", None)
            fan = None if fan is None else np.asarray(fan, dtype=np.float64).reshape(3)
        except (AttributeError, ValueError, TypeError) as exc:
            raise InputError(f"beam must have origin (3,), direction (3,) and optional fan_axis (3,): {exc}") from None
        direction = direction / np.linalg.norm(direction)
        if fan is not None:
            fan = fan - (fan @ direction) * direction
            if np.linalg.norm(fan) < 1e-9:
                raise InputError("beam fan_axis must not be parallel to direction")
            fan = fan / np.linalg.norm(fan)
        return cls(origin, direction, fan)


@dataclass(frozen=True)
class LaserSpec:
    """The laser head: position of the positioner and beam optics.

    Parameters
    ----------
    head_m : (3,) float
        Pivot of the pan-tilt positioner, world metres.
    power_W : float
        Optical power of the spot laser.
    stripe_power_W : float
        Optical power of the line laser (spread over the whole fan, so typically much higher).
    waist_m : float
        1/e² radius of the beam waist (spot) or half-thickness of the sheet at its waist.
    focus_m : float
        Distance from the head to the waist.
    m2 : float
        Beam quality factor M² (>= 1).
    wavelength_m : float
    fan_half_angle_deg : float
        Stripe: half opening angle of the fan.
    """

    head_m: tuple = (0.3, -0.75, 0.75)
    power_W: float = 3e-4
    stripe_power_W: float = 3e-2
    waist_m: float = 2.5e-4
    focus_m: float = 1.1
    m2: float = 1.2
    wavelength_m: float = 650e-9
    fan_half_angle_deg: float = 20.0

    def __post_init__(self):
        for name in ("power_W", "stripe_power_W", "waist_m", "focus_m", "wavelength_m", "fan_half_angle_deg"):
            if not getattr(self, name) > 0:
                raise InputError(f"laser {name} must be positive, got {getattr(self, name)!r}")
        if self.m2 < 1:
            raise InputError(f"laser m2 must be >= 1, got {self.m2!r}")

    @property
    def rayleigh_m(self) -> float:
        """Rayleigh range ``pi w0² / (M² lambda)``, metres."""
        return np.pi * self.waist_m**2 / (self.m2 * self.wavelength_m)


@dataclass(frozen=True)
class GaussianBeams:
    """A set of ``M`` Gaussian beams (one primary spot, or secondary beamlets), arrays of length M."""

    origin: np.ndarray          # (M, 3)
    direction: np.ndarray       # (M, 3) unit
    waist_m: np.ndarray         # (M,)
    focus_m: np.ndarray         # (M,) distance from origin to waist
    rayleigh_m: np.ndarray      # (M,)
    power_W: np.ndarray         # (M,)
    #: (M, 3) normal of the surface a secondary beamlet leaves (None for the laser head): shadow
    #: rays stop at that surface's tangent plane, since the beamlet is emitted by its whole footprint.
    emitter_normal: np.ndarray | None = None
    #: (M, 3) where each beamlet lands and (M,) how far its light reaches around that point: many
    #: beamlets (a reflected stripe) are then evaluated only within reach of where they land.
    landing: np.ndarray | None = None
    reach_m: np.ndarray | None = None

    @cached_property
    def _reach_classes(self) -> list:
        """``(tree, members, largest reach)`` per class of beamlets of similar reach.

        Beamlets are grouped by reach in classes of ratio :data:`_REACH_CLASS_RATIO`; each class
        gets a k-d tree of its landings and the indices ``members`` of its beamlets, built once per
        beam set (a trace serves every camera). Largest reach first: in :meth:`may_light` that
        class settles the most points, so fewer are left open for the others.
        """
        from scipy.spatial import cKDTree

        reach_class = np.floor(np.log(self.reach_m / self.reach_m.min()) / np.log(_REACH_CLASS_RATIO))
        classes = []
        for c in np.unique(reach_class)[::-1]:
            members = np.flatnonzero(reach_class == c)
            classes.append((cKDTree(self.landing[members]), members, float(self.reach_m[members].max())))
        return classes

    def _pairs(self, x: np.ndarray, reach_m: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The (point, beam) pairs worth evaluating at points ``x`` (N, 3), sorted by point, then beam.

        Few beams (or the laser head's): every pair. Beamlets evaluated near their landings: each
        beamlet at every point within its own reach of its landing (plus the point's own
        ``reach_m`` (N,), default 0), found class by class of similar reach
        (:meth:`_reach_classes`) by a search of the points' tree against the class's, within the
        class's largest reach.

        Returns
        -------
        point, beam : ndarray of shape (p,), int
        """
        from scipy.spatial import cKDTree

        n, m = len(x), len(self.power_W)
        if self.landing is None or m <= _MAX_DENSE_BEAMS:
            return np.repeat(np.arange(n), m), np.tile(np.arange(m), n)
        points = cKDTree(x)
        extra_m = 0.0 if reach_m is None else reach_m.max(initial=0.0)
        keys = []
        for tree, members, top_m in self._reach_classes:
            near = points.sparse_distance_matrix(tree, top_m + extra_m, output_type="ndarray")
            beam = members[near["j"]]
            gap_m = near["v"] if reach_m is None else near["v"] - reach_m[near["i"]]
            within = gap_m <= self.reach_m[beam]
            keys.append(near["i"][within].astype(np.int64) * m + beam[within])
        # one sort of point-major keys: the pairs' order, hence every sum over them, does not
        # depend on the search's order (nor on how the points are cut into blocks)
        key = np.sort(np.concatenate(keys))
        return key // m, key % m

    def _axis_coordinates(self, x: np.ndarray, point: np.ndarray, beam: np.ndarray):
        """Distance ``z`` along each pair's beam axis from its origin and squared distance ``rho²``
        from that axis (may round below zero), both (p,), of the (point, beam) pairs of ``x``."""
        rel = np.take(x, point, axis=0) - np.take(self.origin, beam, axis=0)            # (p, 3)
        z = np.einsum("ij,ij->i", rel, np.take(self.direction, beam, axis=0))
        return z, np.einsum("ij,ij->i", rel, rel) - z * z

    def radius(self, z: np.ndarray, idx=slice(None)) -> np.ndarray:
        """1/e² radius at distance ``z`` along the axis (broadcast over beams ``idx``)."""
        return self.waist_m[idx] * np.sqrt(1.0 + ((z - self.focus_m[idx]) / self.rayleigh_m[idx]) ** 2)

    def may_light(self, x: np.ndarray, reach_m: np.ndarray) -> np.ndarray:
        """False where no point within ``reach_m`` of ``x`` gets light from these beams above the
        footprint cut (:data:`FOOTPRINT_RADII` radii off every axis; beamlets evaluated only
        near their landings light nothing beyond their reach of it).

        Parameters
        ----------
        x : ndarray of shape (N, 3)
            Points, world metres.
        reach_m : ndarray of shape (N,)
            Distance around each point, metres.

        Returns
        -------
        ndarray of shape (N,), bool
        """
        may = np.empty(len(x), dtype=bool)
        # blocks of points, as in evaluate: the (point, beam) pairs' memory stays bounded
        for s in range(0, len(x), _EVAL_BLOCK):
            e = min(len(x), s + _EVAL_BLOCK)
            point, beam = self._pairs(x[s:e], reach_m[s:e])
            z, rho2 = self._axis_coordinates(x[s:e], point, beam)
            rho = np.sqrt(np.maximum(rho2, 0.0))
            r = reach_m[s:e][point]
            # the radius is convex in z: its largest value within the reach is at an end
            w = np.maximum(self.radius(z - r, beam), self.radius(z + r, beam))
            lit = (z + r > 0) & (rho - r <= FOOTPRINT_RADII * w)
            may[s:e] = np.bincount(point[lit], minlength=e - s) > 0
        return may

    def evaluate(self, x: np.ndarray):
        """Irradiance across the beams at points, summed over beams.

        Parameters
        ----------
        x : ndarray of shape (N, 3)

        Returns
        -------
        intensity : ndarray of shape (N,)
            W/m² on a surface perpendicular to the propagation.
        propagation : ndarray of shape (N, 3)
            Unit propagation direction of the dominant beam at each point.
        path : ndarray of shape (N,)
            Distance back along the dominant beam's axis to its source (the laser head's exit
            plane, or the emitting surface's tangent plane): the shadow test length.
        """
        n = len(x)
        total = np.zeros(n)
        arg = np.empty(n, dtype=np.int64)
        path = np.empty(n)
        # blocks of points whose (point, beam) scratch arrays stay in the CPU cache
        for s in range(0, n, _EVAL_BLOCK):
            e = min(n, s + _EVAL_BLOCK)
            total[s:e], arg[s:e], path[s:e] = self._evaluate_block(x[s:e])
        propagation = np.take(self.direction, arg, axis=0)
        if self.emitter_normal is not None:
            n_e = np.take(self.emitter_normal, arg, axis=0)
            from_emitter = x - np.take(self.origin, arg, axis=0)
            path = np.einsum("ij,ij->i", from_emitter, n_e) / np.einsum("ij,ij->i", propagation, n_e)
        return total, propagation, path

    def _evaluate_block(self, x: np.ndarray):
        """:meth:`evaluate` at points ``x`` (n, 3): summed irradiance (n,), the dominant beam (n,)
        and the distance along its axis (n,). Where no beam reaches: zero, beam 0, zero.
        """
        n = len(x)
        point, beam = self._pairs(x)                                      # (p,), point-sorted
        z_pair, rho2 = self._axis_coordinates(x, point, beam)
        w = self.radius(z_pair, beam)
        inten_pair = 2 * self.power_W[beam] / (np.pi * w * w) * np.exp(-2 * rho2 / (w * w))
        inten_pair[z_pair <= 0] = 0.0
        total = np.bincount(point, weights=inten_pair, minlength=n)
        arg, z = np.zeros(n, dtype=np.int64), np.zeros(n)
        if point.size:
            # each point's dominant beam: the first of its pairs with the largest irradiance
            starts = np.flatnonzero(np.r_[True, point[1:] != point[:-1]])
            top = np.maximum.reduceat(inten_pair, starts)
            best = np.flatnonzero(inten_pair == np.repeat(top, np.diff(np.r_[starts, point.size])))
            best = best[np.r_[True, point[best[1:]] != point[best[:-1]]]]
            arg[point[best]], z[point[best]] = beam[best], z_pair[best]
        return total, arg, z


@dataclass(frozen=True)
class LightSheet:
    """A fan-shaped plane of light with a Gaussian thickness profile."""

    origin: np.ndarray
    direction: np.ndarray
    fan_axis: np.ndarray
    half_angle_rad: float
    waist_m: float
    focus_m: float
    rayleigh_m: float
    power_W: float

    def radius(self, r: np.ndarray) -> np.ndarray:
        return self.waist_m * np.sqrt(1.0 + ((r - self.focus_m) / self.rayleigh_m) ** 2)

    def may_light(self, x: np.ndarray, reach_m: np.ndarray) -> np.ndarray:
        """False where no point within ``reach_m`` (N,) of ``x`` (N, 3) gets light from the sheet
        above the footprint cut (:data:`FOOTPRINT_RADII` half-thicknesses off its plane); see
        :meth:`GaussianBeams.may_light`."""
        rel = x - self.origin
        off_plane = np.abs(rel @ np.cross(self.direction, self.fan_axis))
        r = np.hypot(rel @ self.fan_axis, rel @ self.direction)
        # the half-thickness is convex in r: its largest value within the reach is at an end
        w = np.maximum(self.radius(r - reach_m), self.radius(r + reach_m))
        return off_plane - reach_m <= FOOTPRINT_RADII * w

    def evaluate(self, x: np.ndarray):
        """Irradiance of the sheet at points (see :meth:`GaussianBeams.evaluate`)."""
        normal = np.cross(self.direction, self.fan_axis)
        rel = x - self.origin
        s = rel @ normal
        a, d = rel @ self.fan_axis, rel @ self.direction
        r = np.hypot(a, d)
        w = self.radius(r)
        with np.errstate(divide="ignore", invalid="ignore"):
            inten = (self.power_W / (2 * self.half_angle_rad) / r * np.sqrt(2 / np.pi) / w
                     * np.exp(-2 * s * s / (w * w)))
        inside = (d > 0) & (np.abs(np.arctan2(a, d)) <= self.half_angle_rad)
        inten = np.where(inside, inten, 0.0)
        dist = np.linalg.norm(rel, axis=1)
        return inten, rel / np.maximum(dist, 1e-300)[:, None], dist


@dataclass
class LaserTrace:
    """Everything one laser pose does to the scene.

    Attributes
    ----------
    sources : list of GaussianBeams or LightSheet
        Emitters to evaluate when shading (primary, then secondary beamlets).
    truth_points : ndarray of shape (K, 3)
        Centre-line hits, world metres.
    truth_kind : list of str
        ``"primary"`` or ``"secondary"`` per truth point.
    footprint_points, footprint_radius_m : ndarray (F, 3), (F,)
        Where light lands and how far it spreads (for render windows).
    """

    sources: list = field(default_factory=list)
    truth_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    truth_kind: list = field(default_factory=list)
    footprint_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    footprint_radius_m: np.ndarray = field(default_factory=lambda: np.zeros(0))


def reflect(d: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Mirror directions ``d - 2 (d·n) n`` for rows of unit vectors."""
    return d - 2.0 * np.einsum("ij,ij->i", d, n)[:, None] * n


def trace_laser(pose: BeamPose, spec: LaserSpec, scene) -> LaserTrace:
    """Cast a laser pose into the scene: primary hits, secondary beamlets and their hits.

    Parameters
    ----------
    pose : BeamPose
        ``fan_axis`` None for a spot, set for a stripe.
    spec : LaserSpec
    scene : Scene

    Returns
    -------
    LaserTrace
    """
    caster = scene.raycaster
    if pose.fan_axis is None:
        source = GaussianBeams(pose.origin[None], pose.direction[None], np.array([spec.waist_m]),
                               np.array([spec.focus_m]), np.array([spec.rayleigh_m]), np.array([spec.power_W]))
        dirs = pose.direction[None]
        power_per_ray = np.array([spec.power_W])
        truth_stride = 1
    else:
        half = np.radians(spec.fan_half_angle_deg)
        source = LightSheet(pose.origin, pose.direction, pose.fan_axis, half, spec.waist_m, spec.focus_m,
                            spec.rayleigh_m, spec.stripe_power_W)
        phi = np.linspace(-half, half, N_FAN_SAMPLES)
        dirs = np.cos(phi)[:, None] * pose.direction + np.sin(phi)[:, None] * pose.fan_axis
        power_per_ray = np.full(N_FAN_SAMPLES, spec.stripe_power_W / N_FAN_SAMPLES)
        truth_stride = N_FAN_SAMPLES // N_FAN_TRUTH
    origins = np.broadcast_to(pose.origin, dirs.shape)
    hits = caster.cast(origins, dirs)
    ok = hits.hit
    p, n_geo, n_sh, t = hits.point[ok], hits.normal[ok], hits.shading_normal[ok], hits.t[ok]
    cos_i = np.abs(np.einsum("ij,ij->i", dirs[ok], n_geo))
    radius0 = _source_radius(source, t)
    trace = LaserTrace(sources=[source])
    keep = np.flatnonzero(ok)
    truth_sel = (keep % truth_stride) == 0
    truth = [p[truth_sel]]
    kinds = ["primary"] * int(truth_sel.sum())
    fp_pts = [p]
    fp_rad = [FOOTPRINT_RADII * radius0 / np.maximum(cos_i, MIN_COS_FOOTPRINT)]

    # secondary beamlets from shiny hits
    mats = scene.materials
    spec_frac = np.array([m.specular for m in mats])[hits.obj[ok]]
    rough = np.array([m.roughness_rad for m in mats])[hits.obj[ok]]
    shiny = spec_frac > 0
    if np.any(shiny):
        r_dir = reflect(dirs[ok][shiny], n_sh[shiny])
        w_start = radius0[shiny]
        beamlets = GaussianBeams(p[shiny] + SURFACE_EPS_M * n_geo[shiny], r_dir, w_start, np.zeros(len(w_start)),
                                 w_start / (2 * rough[shiny]), spec_frac[shiny] * power_per_ray[ok][shiny],
                                 emitter_normal=n_geo[shiny])
        h2 = caster.cast(beamlets.origin, r_dir)
        ok2 = h2.hit
        if np.any(ok2):
            q = h2.point[ok2]
            cos2 = np.abs(np.einsum("ij,ij->i", r_dir[ok2], h2.normal[ok2]))
            w2 = beamlets.radius(h2.t[ok2], np.flatnonzero(ok2))
            reach = FOOTPRINT_RADII * w2 / np.maximum(cos2, MIN_COS_FOOTPRINT)
            landed = {f.name: getattr(beamlets, f.name)[ok2] for f in dataclasses.fields(beamlets)
                      if getattr(beamlets, f.name) is not None}
            fan = keep[shiny][ok2]
            landed = merge_overlapping({**landed, "landing": q, "reach_m": reach}, w2, fan,
                                       hits.obj[ok][shiny][ok2], h2.obj[ok2])
            trace.sources.append(GaussianBeams(**landed))
            sel2 = (fan % truth_stride) == 0
            truth.append(q[sel2])
            kinds += ["secondary"] * int(sel2.sum())
            fp_pts.append(q)
            fp_rad.append(reach)
    trace.truth_points = np.vstack(truth)
    trace.truth_kind = kinds
    trace.footprint_points = np.vstack(fp_pts)
    trace.footprint_radius_m = np.concatenate(fp_rad)
    return trace


def _source_radius(source, t: np.ndarray) -> np.ndarray:
    """1/e² radius (spot) or half-thickness (sheet) of the primary light at distance ``t``."""
    return source.radius(t) if isinstance(source, LightSheet) else source.radius(t, 0)


def raster_poses(spec: LaserSpec, center_m, radius_m: float, n_frames: int, mode: str) -> list[BeamPose]:
    """Beam poses of a plain pan/tilt raster from the laser head covering a sphere of interest.

    Spots follow a serpentine grid of about ``n_frames`` pan × tilt angles (truncated to
    ``n_frames``); stripes are vertical-ish fans swept in pan.

    Parameters
    ----------
    spec : LaserSpec
    center_m : (3,) float
        Centre of the region to cover, world metres.
    radius_m : float
        Its radius, metres.
    n_frames : int
    mode : {"spot", "stripe"}

    Returns
    -------
    list of BeamPose
    """
    from scipy.spatial.transform import Rotation

    if mode not in ("spot", "stripe"):
        raise InputError(f"mode must be 'spot' or 'stripe', got {mode!r}")
    if not isinstance(n_frames, (int, np.integer)) or n_frames < 1:
        raise InputError(f"n_frames must be a positive integer, got {n_frames!r}")
    head = np.asarray(spec.head_m, dtype=np.float64)
    aim = np.asarray(center_m, dtype=np.float64) - head
    dist = np.linalg.norm(aim)
    central = aim / dist
    up = np.array([0.0, 0.0, 1.0])
    tilt_axis = np.cross(central, up)
    tilt_axis /= np.linalg.norm(tilt_axis)
    fan_axis = np.cross(tilt_axis, central)
    half = np.arctan2(radius_m, dist)
    poses = []
    if mode == "spot":
        n_side = int(np.ceil(np.sqrt(n_frames)))
        grid = np.linspace(-half, half, n_side)
        for j, tilt in enumerate(grid):
            pans = grid if j % 2 == 0 else grid[::-1]
            for pan in pans:
                R = Rotation.from_rotvec(pan * fan_axis) * Rotation.from_rotvec(tilt * tilt_axis)
                poses.append(BeamPose(head, R.apply(central)))
        return poses[:n_frames]
    for pan in np.linspace(-half, half, n_frames):
        R = Rotation.from_rotvec(pan * fan_axis)
        poses.append(BeamPose(head, R.apply(central), fan_axis.copy()))
    return poses
