"""Light planes: robust fitting to 3-D points and ray–plane intersection with uncertainty.

Two uses. In stripe mode the plane of each frame is fitted to that frame's multi-view points, so
that stripe points seen by a single camera can still be placed (and points that are not on the
plane, such as reflections, rejected). In the classic single-camera mode of the source's §3 the
plane is calibrated once from the stripe on the calibration target at several poses
(:mod:`scanrig.reconstruct.light_plane_fit`), and every stripe point is its ray's intersection
with it.

A plane is ``n · x = d`` with unit normal ``n`` (world frame) and offset ``d`` (metres). Its
uncertainty at a point ``x`` is the standard deviation of the fitted plane's signed distance
there, from the least-squares regression formula.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from scanrig.errors import EstimationError, InputError
from scanrig.geometry.checks import check_points

#: RANSAC trials: with half the candidates on the plane, 200 draws of 3 miss a clean sample with
#: probability (1 − 0.5³)^200 ≈ 2.6e-12.
RANSAC_TRIALS = 200
#: Inlier gate, in standard deviations of a point's distance to the plane.
INLIER_SIGMAS = 3.0
#: Fewest inliers for a plane to be trusted (a stripe frame has hundreds).
MIN_PLANE_POINTS = 10
#: Blocks of the jackknife that measures a plane's uncertainty under correlated errors.
JACKKNIFE_BLOCKS = 10


@dataclass(frozen=True)
class LightPlane:
    """A fitted plane ``normal · x = offset`` (world frame).

    Attributes
    ----------
    normal : ndarray of shape (3,)
        Unit normal.
    offset : float
        Signed distance of the plane from the origin along ``normal``, metres.
    centroid : ndarray of shape (3,)
        Mean of the inliers, metres.
    axes : ndarray of shape (2, 3)
        In-plane principal directions of the inliers.
    spread_m2 : ndarray of shape (2,)
        ``Σ ((p − centroid) · axis)²`` over the inliers, m².
    residual_m : float
        RMS distance of the inliers to the plane, metres.
    n_inliers : int or float
        Inliers of the fit (an effective, smaller number after :func:`with_block_uncertainty`).
    """

    normal: np.ndarray
    offset: float
    centroid: np.ndarray
    axes: np.ndarray
    spread_m2: np.ndarray
    residual_m: float
    n_inliers: float

    def distance(self, p_world: np.ndarray) -> np.ndarray:
        """Signed distances ``(N,)`` of points ``(N, 3)`` to the plane, metres."""
        return p_world @ self.normal - self.offset

    def offset_sigma(self, p_world: np.ndarray) -> np.ndarray:
        """Standard deviation ``(N,)`` of the fitted plane's position at points ``(N, 3)``, metres."""
        rel = p_world - self.centroid
        lever = ((rel @ self.axes.T) ** 2 / self.spread_m2).sum(axis=1)
        return self.residual_m * np.sqrt(1.0 / self.n_inliers + lever)

    def tilt_sigma_rad(self) -> np.ndarray:
        """Standard deviation ``(2,)`` of the normal's tilt towards each of :attr:`axes`, radians."""
        return self.residual_m / np.sqrt(self.spread_m2)

    def offset_sigma_m(self) -> float:
        """Standard deviation of :attr:`offset` (the plane's position at the world origin), metres."""
        return float(self.offset_sigma(np.zeros((1, 3)))[0])


def fit_plane(p_world: np.ndarray, weights: np.ndarray | None = None) -> LightPlane:
    """Least-squares plane through points (smallest principal axis).

    Parameters
    ----------
    p_world : ndarray of shape (N, 3)
        Points, N >= 3, metres.
    weights : ndarray of shape (N,), optional
        Non-negative weights (inverse variances of the distances). With weights the plane's
        ``residual_m`` is the weighted RMS distance and ``spread_m2`` is ``N`` times the weighted
        mean square along each axis, so that :meth:`LightPlane.offset_sigma` is the weighted
        least-squares standard deviation of the plane's position (scaled by the observed
        residuals); without weights both are the plain sums.

    Raises
    ------
    EstimationError
        If fewer than 3 points or they are collinear.
    """
    p = check_points(p_world, 3, "p_world")
    w = np.ones(len(p)) if weights is None else np.asarray(weights, np.float64)
    if len(p) < 3:
        raise EstimationError(f"a plane needs at least 3 points, got {len(p)}")
    w_mean = w / w.sum()
    centroid = (w_mean[:, None] * p).sum(axis=0)
    rel = p - centroid
    M = (w[:, None] * rel).T @ rel
    eigval, eigvec = np.linalg.eigh(M)
    if eigval[1] <= 1e-12 * max(eigval[2], 1e-300):
        raise EstimationError("the points are collinear: no plane is defined")
    normal = eigvec[:, 0]
    axes = eigvec[:, 1:].T
    dist = rel @ normal
    spread = len(p) * (w_mean[:, None] * (rel @ axes.T) ** 2).sum(axis=0)
    return LightPlane(normal, float(centroid @ normal), centroid, axes, spread,
                      float(np.sqrt(np.sum(w_mean * dist**2))), len(p))


def fit_plane_robust(p_world: np.ndarray, sigma_m: np.ndarray | None, rng: np.random.Generator,
                     inlier_sigmas: float = INLIER_SIGMAS, trials: int = RANSAC_TRIALS,
                     cov_m: np.ndarray | None = None):
    """RANSAC plane followed by weighted least-squares refits on the inliers.

    Parameters
    ----------
    p_world : ndarray of shape (N, 3)
        Candidate points, metres.
    sigma_m : ndarray of shape (N,) or None
        Standard deviation of each point along the plane normal (or its largest axis), metres.
        May be None when ``cov_m`` is given.
    rng : numpy.random.Generator
        For the RANSAC samples.
    inlier_sigmas : float
        A point is an inlier when its distance is below ``inlier_sigmas · sqrt(σ² + σ_plane²)``.
    trials : int
        RANSAC samples.
    cov_m : ndarray of shape (N, 3, 3), optional
        Full covariances of the points, m². Then ``σ`` is each point's standard deviation along
        the normal of the plane being tested (``nᵀ Σ n``): points that are precise across the
        plane but not along it (triangulated with rays nearly in the plane) are weighted by what
        they say about the plane, the samples are drawn from the points whose largest axis is
        at most the median, and the points' own noise is taken out of the plane's in-plane
        extent (:func:`_without_noise_spread`), so that a straight stripe is not mistaken for a
        plane whose tilt it determines.

    Returns
    -------
    plane : LightPlane or None
        None when fewer than :data:`MIN_PLANE_POINTS` inliers support any plane.
    inliers : ndarray of shape (N,), bool
    """
    p = check_points(p_world, 3, "p_world")
    n = len(p)
    none = (None, np.zeros(n, bool))
    if n < MIN_PLANE_POINTS:
        return none
    if cov_m is not None:
        cov = np.asarray(cov_m, np.float64)
        largest = np.sqrt(np.maximum(np.linalg.eigvalsh(cov)[:, -1], 0.0))
        pool = np.flatnonzero(largest <= np.median(largest))
        if pool.size < 3:
            pool = np.arange(n)

        def sigma_along(normal):
            return np.sqrt(np.maximum(np.einsum("i,nij,j->n", normal, cov, normal), 0.0))
    else:
        sigma = np.asarray(sigma_m, np.float64)
        pool = np.arange(n)

        def sigma_along(normal):
            return sigma
    samples = np.stack([rng.choice(pool, 3, replace=False) for _ in range(trials)])
    normals, offsets = planes_through(p[samples])
    if len(normals) == 0:
        return none
    if cov_m is not None:
        # optimize: (cov n) first, then the dot with n; unoptimised einsum loops over every
        # (point, trial, i, j), 16 times slower on 30 000 points (an 8-camera frame)
        s_all = np.sqrt(np.maximum(np.einsum("ti,nij,tj->nt", normals, cov, normals, optimize=True), 0.0))
    else:
        s_all = sigma[:, None]
    inlier_counts = (np.abs(p @ normals.T - offsets) <= inlier_sigmas * s_all).sum(axis=0)
    best = int(np.argmax(inlier_counts))
    s = sigma_along(normals[best])
    inliers = np.abs(p @ normals[best] - offsets[best]) <= inlier_sigmas * s
    plane = None
    for _ in range(3 if cov_m is not None else 2):
        if inliers.sum() < MIN_PLANE_POINTS:
            return none
        w = 1.0 / np.maximum(s[inliers], 1e-12) ** 2
        try:
            plane = fit_plane(p[inliers], w)
        except EstimationError:
            return none
        if cov_m is not None:
            plane = _without_noise_spread(plane, w, cov[inliers])
        s = sigma_along(plane.normal)
        gate = inlier_sigmas * np.sqrt(s**2 + plane.offset_sigma(p) ** 2)
        inliers = np.abs(plane.distance(p)) <= gate
    return plane, inliers


def planes_through(triples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Planes through point triples ``(T, 3, 3)``: unit normals ``(T', 3)`` and offsets ``(T',)``,
    degenerate (collinear) triples left out."""
    a, b, c = triples[:, 0], triples[:, 1], triples[:, 2]
    normals = np.cross(b - a, c - a)
    norm = np.linalg.norm(normals, axis=1)
    valid = norm > 0
    normals = normals[valid] / norm[valid, None]
    return normals, np.einsum("ij,ij->i", normals, a[valid])


def _without_noise_spread(plane: LightPlane, w: np.ndarray, cov: np.ndarray) -> LightPlane:
    """The plane with the points' own noise removed from its in-plane spread (errors in variables).

    The tilt of a fitted plane about an in-plane axis is known from how far the points extend
    across that axis. When they extend no farther than their own noise (a stripe that is a
    straight line in space, whose points scatter along their rays), the fit takes the noise for
    extent and reports a tilt that is not there. Subtracting the expected noise moment
    ``Σ w aᵀ Σ_k a`` (normalised like ``spread_m2``) leaves the true extent; where nothing is
    left, the spread becomes tiny and :meth:`LightPlane.offset_sigma` grows without bound away
    from the line, so the plane is used only where it is known.
    """
    w_mean = w / w.sum()
    noise = len(w) * np.einsum("n,ai,nij,aj->a", w_mean, plane.axes, cov, plane.axes)
    spread = np.maximum(plane.spread_m2 - noise, 1e-6 * plane.spread_m2)
    return dataclasses.replace(plane, spread_m2=spread)


def with_block_uncertainty(plane: LightPlane, p_world: np.ndarray, weights: np.ndarray,
                           n_blocks: int = JACKKNIFE_BLOCKS) -> LightPlane:
    """The plane with its uncertainty widened to what a block jackknife along the stripe shows.

    :meth:`LightPlane.offset_sigma` assumes independent errors: ``N`` points make the offset
    ``sqrt(N)`` times better known than one. Points of one stripe share smooth errors (the
    calibration's, which bend a straight stripe), so the inliers are cut into ``n_blocks``
    contiguous blocks along the plane's long axis, the blocks of
    :func:`with_jackknife_uncertainty`.

    Parameters
    ----------
    plane, p_world, weights
        As for :func:`with_jackknife_uncertainty`: the plane, its inliers ``(N, 3)`` (metres) and
        their weights ``(N,)``.
    n_blocks : int
        Jackknife blocks (at least 3 points each, else the plane is returned unchanged).
    """
    n = len(p_world)
    if n < 3 * n_blocks or plane.residual_m <= 0:
        return plane
    along = (p_world - plane.centroid) @ plane.axes[1]
    block = np.empty(n, int)
    block[np.argsort(along, kind="stable")] = np.arange(n) * n_blocks // n
    return with_jackknife_uncertainty(plane, p_world, weights, block)


def with_jackknife_uncertainty(plane: LightPlane, p_world: np.ndarray, weights: np.ndarray,
                               block: np.ndarray, variance_factor: float = 1.0) -> LightPlane:
    """The plane with its uncertainty widened to what a delete-one-block jackknife shows.

    The plane is refitted without each block in turn; the jackknife variances of its offset (at
    the centroid) and of its two tilts replace the independent-error ones where they are larger,
    expressed as an effective number of points and effective spreads so that
    :meth:`LightPlane.offset_sigma` keeps its meaning.

    Parameters
    ----------
    plane : LightPlane
        Fitted to ``p_world`` with ``weights``.
    p_world : ndarray of shape (N, 3)
        Its inliers, metres.
    weights : ndarray of shape (N,)
        Their weights in the fit.
    block : ndarray of shape (N,), int
        Block label of each point (a stretch of stripe, a pose of the target); errors are
        taken as independent between blocks and arbitrary within one. With fewer than 3 blocks,
        or a refit that fails, the plane is returned unchanged.
    variance_factor : float
        Multiplies the jackknife variances (see :func:`fit_light_plane` for the small-sample
        factor used with few blocks).
    """
    labels = np.unique(block)
    if len(labels) < 3 or plane.residual_m <= 0:
        return plane
    refits = []
    for k in labels:
        keep = block != k
        try:
            refits.append(fit_plane(p_world[keep], weights[keep]))
        except EstimationError:
            return plane
    offsets, tilts = _offsets_and_tilts(plane, refits)
    factor = variance_factor * (len(labels) - 1) / len(labels)
    var_offset = factor * np.sum((offsets - offsets.mean()) ** 2)
    var_tilt = factor * np.sum((tilts - tilts.mean(axis=0)) ** 2, axis=0)
    r2 = plane.residual_m**2
    n_eff = min(float(plane.n_inliers), r2 / max(var_offset, 1e-300))
    spread = np.minimum(plane.spread_m2, r2 / np.maximum(var_tilt, 1e-300))
    return dataclasses.replace(plane, n_inliers=n_eff, spread_m2=spread)


def with_sampled_uncertainty(plane: LightPlane, p_samples) -> LightPlane:
    """The plane with the spread of refits on re-computed points added to its variances.

    The points of a light-plane calibration are made with the calibrated camera and target
    poses; recomputed with calibrations drawn from the calibration's covariance, each set gives
    a refitted plane. The variances of their offsets (at ``plane.centroid``) and tilts are the
    calibration's contribution, shared by every point and every pose, which neither the
    residuals nor a jackknife over poses can see (a focal length off by 1e-4 moves every point
    by 1e-4 of its range). They are added to the plane's own variances, expressed again as an
    effective number of points and effective spreads.

    Parameters
    ----------
    plane : LightPlane
    p_samples : sequence of ndarray of shape (N, 3)
        The plane's inliers recomputed with each sampled calibration, metres (at least 2 sets).
    """
    if len(p_samples) < 2 or plane.residual_m <= 0:
        return plane
    offsets, tilts = _offsets_and_tilts(plane, [fit_plane(p) for p in p_samples])
    r2 = plane.residual_m**2
    var_offset = r2 / plane.n_inliers + np.var(offsets, ddof=1)
    var_tilt = r2 / plane.spread_m2 + np.var(tilts, axis=0, ddof=1)
    return dataclasses.replace(plane, n_inliers=float(r2 / var_offset), spread_m2=r2 / var_tilt)


def _offsets_and_tilts(plane: LightPlane, refits) -> tuple[np.ndarray, np.ndarray]:
    """Positions ``(K,)`` of refitted planes at ``plane.centroid`` (metres, along ``plane.normal``)
    and their normals' tilts ``(K, 2)`` towards ``plane.axes`` (radians)."""
    offsets, tilts = [], []
    for sub in refits:
        sign = 1.0 if sub.normal @ plane.normal >= 0 else -1.0
        offsets.append(plane.centroid @ (sign * sub.normal) - sign * sub.offset)
        tilts.append(plane.axes @ (sign * sub.normal))
    return np.array(offsets), np.array(tilts)


def intersect_plane(centers: np.ndarray, dirs: np.ndarray, plane: LightPlane):
    """Intersections of rays with a plane.

    Parameters
    ----------
    centers : ndarray of shape (N, 3)
        Ray origins, metres.
    dirs : ndarray of shape (N, 3)
        Unit directions.
    plane : LightPlane

    Returns
    -------
    p_world : ndarray of shape (N, 3)
        Intersections; NaN where the ray is parallel to the plane or hits it behind its origin.
    t : ndarray of shape (N,)
        Range along the ray, metres.
    """
    denom = dirs @ plane.normal
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (plane.offset - centers @ plane.normal) / denom
    bad = ~(t > 0) | (np.abs(denom) < 1e-9)
    p = centers + t[:, None] * dirs
    p[bad] = np.nan
    t = np.where(bad, np.nan, t)
    return p, t


def ray_plane_covariance(dirs: np.ndarray, t: np.ndarray, sigma_ray_rad: np.ndarray, plane: LightPlane,
                         p_world: np.ndarray) -> np.ndarray:
    """First-order covariance ``(N, 3, 3)`` of ray–plane intersections, m².

    Two sources: the ray's angular error ``sigma_ray_rad`` (pixel sigma over focal length) moves
    the intersection within the plane by ``t · δ`` stretched by the incidence; the plane's own
    position error at the point moves it along the ray by ``σ_plane / |n · d|``.
    """
    n = plane.normal
    nd = dirs @ n
    # Two unit vectors perpendicular to each ray.
    helper = np.where(np.abs(dirs[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    e1 = np.cross(dirs, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(dirs, e1)
    cov = np.zeros((len(dirs), 3, 3))
    for e in (e1, e2):
        # d(t d)/d(angle along e) = t (e − d (n·e)/(n·d))
        v = (t * sigma_ray_rad)[:, None] * (e - dirs * ((e @ n) / nd)[:, None])
        cov += v[:, :, None] * v[:, None, :]
    along = (plane.offset_sigma(p_world) / np.abs(nd))[:, None] * dirs
    cov += along[:, :, None] * along[:, None, :]
    return cov


def plane_from(normal, offset: float) -> LightPlane:
    """A bare plane ``normal · x = offset`` (for intersections; no uncertainty)."""
    normal = np.asarray(normal, np.float64)
    length = np.linalg.norm(normal)
    return LightPlane(normal / length, float(offset) / length, normal / length * float(offset) / length,
                      np.eye(3)[:2], np.ones(2), 0.0, 1)


#: Keys of a light-plane file (``light_plane.toml``).
_PLANE_KEYS = ("format_version", "units", "camera", "normal", "offset_m", "centroid_m", "axes", "spread_m2",
               "residual_m", "n_inliers")
#: Optional keys: the plane's sigmas as numbers (derived from the keys above, for readers) and
#: the calibration's provenance.
_PLANE_OPTIONAL_KEYS = ("normal_sigma_rad", "offset_sigma_m", "n_poses", "laser_color")


def save_light_plane(path, plane: LightPlane, camera: str, comments=(), extra: dict | None = None) -> None:
    """Write a calibrated light plane as TOML (atomically), for the camera whose stripe it explains.

    Besides the plane and the terms of its uncertainty the file carries ``normal_sigma_rad``
    (:meth:`LightPlane.tilt_sigma_rad`) and ``offset_sigma_m`` (:meth:`LightPlane.offset_sigma_m`);
    ``extra`` may add ``n_poses`` and ``laser_color``.
    """
    import tomli_w

    from scanrig.io.atomic import write_text_atomic

    extra = dict(extra or {})
    unknown = sorted(set(extra) - set(_PLANE_OPTIONAL_KEYS[2:]))
    if unknown:
        raise InputError(f"extra may hold {list(_PLANE_OPTIONAL_KEYS[2:])}, got {unknown}")
    doc = {"format_version": 1, "units": "m", "camera": camera, "normal": plane.normal.tolist(),
           "offset_m": plane.offset, "centroid_m": plane.centroid.tolist(), "axes": plane.axes.tolist(),
           "spread_m2": plane.spread_m2.tolist(), "residual_m": plane.residual_m,
           "n_inliers": float(plane.n_inliers), "normal_sigma_rad": plane.tilt_sigma_rad().tolist(),
           "offset_sigma_m": plane.offset_sigma_m(), **extra}
    header = "".join(f"# {line}\n" for line in ("light plane: normal . x = offset_m (world frame)", *comments))
    write_text_atomic(path, header + tomli_w.dumps(doc))


def load_light_plane(path) -> tuple[LightPlane, str]:
    """Read a light-plane file; returns the plane and its camera name.

    Raises
    ------
    FileFormatError
        If the file is missing, malformed, or lacks a field.
    """
    from pathlib import Path

    from scanrig.errors import FileFormatError
    from scanrig.io.toml_fields import check_keys, read_toml

    path = Path(path)
    doc = read_toml(path)
    check_keys(doc, _PLANE_KEYS + _PLANE_OPTIONAL_KEYS, _PLANE_KEYS, path, "top level")
    try:
        normal = np.asarray(doc["normal"], np.float64)
        plane = LightPlane(normal / np.linalg.norm(normal), float(doc["offset_m"]),
                           np.asarray(doc["centroid_m"], np.float64), np.asarray(doc["axes"], np.float64),
                           np.asarray(doc["spread_m2"], np.float64), float(doc["residual_m"]), float(doc["n_inliers"]))
    except (TypeError, ValueError) as exc:
        raise FileFormatError(path, f"malformed light plane: {exc}") from None
    if plane.normal.shape != (3,) or plane.axes.shape != (2, 3) or plane.spread_m2.shape != (2,):
        raise FileFormatError(path, "normal must have 3 numbers, axes 2x3 and spread_m2 2")
    return plane, str(doc["camera"])


def intersect_stripe_pixels(camera, q, cov_px, plane: LightPlane):
    """Classic single-camera triangulation: stripe pixels intersected with a calibrated plane.

    Parameters
    ----------
    camera : Camera
    q : ndarray of shape (N, 2)
        Stripe centres, pixels.
    cov_px : ndarray of shape (N, 2, 2)
        Their covariances, px².
    plane : LightPlane

    Returns
    -------
    p_world : ndarray of shape (N, 3)
        Points (NaN where the ray misses the plane).
    cov : ndarray of shape (N, 3, 3)
        First-order covariances, m².
    """
    centers, dirs = camera.rays(q)
    p, t = intersect_plane(centers, dirs, plane)
    focal = np.sqrt(camera.params[0] * camera.params[1])
    sigma_rad = np.sqrt(0.5 * np.trace(cov_px, axis1=1, axis2=2)) / focal
    cov = np.full((len(q), 3, 3), np.nan)
    ok = np.all(np.isfinite(p), axis=1)
    cov[ok] = ray_plane_covariance(dirs[ok], t[ok], sigma_rad[ok], plane, p[ok])
    return p, cov
