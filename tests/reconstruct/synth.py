"""Synthetic rigs and laser traces for the reconstruction tests and benchmark.

The truth is built by projecting known points with ``Camera.project`` and adding Gaussian pixel
noise of known sigma; no reconstruction code is used, so the estimators are tested against an
independent truth.
"""

from __future__ import annotations

import numpy as np

from scanrig.geometry import Camera, Rig, RigidTransform

#: Focal length of the synthetic cameras (px): a 16 mm lens on 6.7 µm pixels, as in the notes §3.
FOCAL_PX = 2400.0
WIDTH, HEIGHT = 1280, 1024
#: Mild OpenCV-5 distortion so that every path goes through the Newton undistortion.
DIST = (-0.08, 0.05, 0.0005, -0.0003, 0.0)


def look_at(center: np.ndarray, target: np.ndarray = np.zeros(3)) -> RigidTransform:
    """``cam_from_world`` of a camera at ``center`` looking at ``target`` (world z up)."""
    z = target - center
    z = z / np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return RigidTransform(R, -R @ center)


def ring_rig(azimuths_deg=(-40.0, 0.0, 40.0), radius_m=1.0, height_m=0.2, model="opencv5") -> Rig:
    """Cameras on a horizontal arc around the origin, all looking at it (the notes' §3 layout)."""
    cams = []
    for k, az in enumerate(np.deg2rad(azimuths_deg)):
        center = np.array([radius_m * np.sin(az), -radius_m * np.cos(az), height_m * (1 + 0.5 * (k % 2))])
        dist = DIST if model == "opencv5" else ()
        params = [FOCAL_PX, FOCAL_PX, WIDTH / 2 - 0.5, HEIGHT / 2 - 0.5, *dist]
        cams.append(Camera(f"cam{k}", model, params, WIDTH, HEIGHT, look_at(center)))
    return Rig(cams)


def points_in_cube(rng: np.random.Generator, n: int, half_m: float = 0.15) -> np.ndarray:
    """``n`` points uniform in a cube of half-size ``half_m`` at the origin, metres."""
    return rng.uniform(-half_m, half_m, (n, 3))


def observe(rig: Rig, p_world: np.ndarray, rng: np.random.Generator, sigma_px: float) -> np.ndarray:
    """Noisy pixels ``(n_cams, N, 2)`` of points (NaN outside an image)."""
    q = np.stack([cam.project(p_world) for cam in rig.cameras])
    q = q + rng.normal(0.0, sigma_px, q.shape)
    size = np.array([WIDTH, HEIGHT])
    outside = np.any((q < -0.5) | (q > size - 0.5), axis=2)
    q[outside] = np.nan
    return q


def spot_traces(rig: Rig, p_world: np.ndarray, rng: np.random.Generator, sigma_px: float,
                reflection_rate: float = 0.0, occlusion_rate: float = 0.0, shift_px=(8.0, 60.0)):
    """A traces table of spot candidates for one spot per frame, with injected reflections.

    Each frame ``k`` shows the spot ``p_world[k]`` (noise ``sigma_px``); with probability
    ``occlusion_rate`` a camera misses the true spot; with probability ``reflection_rate`` a
    camera also sees a reflection: an extra candidate shifted by ``shift_px`` in a random
    direction, brighter (rank 0) half of the time.

    Returns
    -------
    table : pyarrow.Table
        Traces (``docs/architecture.md``), frames named ``f0000``...
    is_reflection : dict
        ``(camera, frame) -> bool array`` over that camera's candidates, in rank order.
    """
    import pyarrow as pa

    from scanrig.laser.traces import SCHEMA

    q = observe(rig, p_world, rng, sigma_px)
    rows, truth = [], {}
    for k in range(p_world.shape[0]):
        frame = f"f{k:04d}"
        for i, cam in enumerate(rig.cameras):
            cands = []
            if np.isfinite(q[i, k]).all() and rng.random() >= occlusion_rate:
                cands.append((q[i, k], False))
            if rng.random() < reflection_rate:
                angle = rng.uniform(0, 2 * np.pi)
                shift = rng.uniform(*shift_px)
                base = q[i, k] if np.isfinite(q[i, k]).all() else np.array([WIDTH / 2, HEIGHT / 2])
                reflection = (base + shift * np.array([np.cos(angle), np.sin(angle)]), True)
                cands.insert(int(rng.random() < 0.5) * len(cands), reflection)
            for rank, (uv, _) in enumerate(cands):
                rows.append((cam.name, frame, uv[0], uv[1], rank))
            if cands:
                truth[(cam.name, frame)] = np.array([c[1] for c in cands])
    n = len(rows)
    cols = dict(zip(("camera", "frame", "u", "v", "rank"), map(list, zip(*rows))))
    cols.update(kind=["spot"] * n, sigma_px=np.full(n, sigma_px), peak=np.full(n, 200.0),
                width_px=np.full(n, 1.5), snr=np.full(n, 100.0), cov_uu=np.full(n, sigma_px**2),
                cov_uv=np.zeros(n), cov_vv=np.full(n, sigma_px**2), line=np.full(n, -1, np.int32),
                saturated=np.zeros(n, bool))
    return pa.Table.from_pydict({f.name: cols[f.name] for f in SCHEMA}, schema=SCHEMA), truth


def reflection_outcome(rig: Rig, frames: list[str], truth: dict, matches) -> tuple[int, int]:
    """Reflection candidates of :func:`spot_traces` and how many the matching left out.

    Parameters
    ----------
    rig : Rig
    frames : list of str
        Frame order of ``matches``.
    truth : dict
        ``(camera, frame) -> (n_candidates,) bool`` reflection flags from :func:`spot_traces`.
    matches : SpotMatches
        The matching result (``status`` per frame, ``choice`` per frame and camera).

    Returns
    -------
    n_reflections, n_rejected : int
    """
    from scanrig.reconstruct.correspondence import FrameStatus

    n_refl = rejected = 0
    for (cam, frame), is_refl in truth.items():
        i, f = rig.names.index(cam), frames.index(frame)
        for k in np.flatnonzero(is_refl):
            n_refl += 1
            rejected += matches.status[f] != FrameStatus.MATCHED or matches.choice[f, i] != k
    return n_refl, rejected


def two_camera_table(uv_by_camera, sigma_px=0.3):
    """Spot traces of frame ``f0`` from ``camera -> (n, 2)`` pixels, ranked in order."""
    import pyarrow as pa

    from scanrig.laser.traces import make_table

    tables = []
    for name, uv in uv_by_camera.items():
        uv = np.atleast_2d(uv)
        n = len(uv)
        cols = dict(u=uv[:, 0], v=uv[:, 1], sigma_px=np.full(n, sigma_px), peak=np.full(n, 100.0),
                    width_px=np.full(n, 1.5), snr=np.full(n, 50.0), rank=np.arange(n, dtype=np.int32),
                    cov_uu=np.full(n, sigma_px**2), cov_uv=np.zeros(n), cov_vv=np.full(n, sigma_px**2),
                    line=np.full(n, -1, np.int32), saturated=np.zeros(n, bool))
        tables.append(make_table("spot", cols, camera=name, frame="f0"))
    return pa.concat_tables(tables)


def height_field(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The wavy test surface ``z = h(x, y)`` (metres) of the stripe tests."""
    return 0.015 * np.sin(8.0 * x) * np.cos(6.0 * y)


def stripe_traces(rig: Rig, offsets_m, rng: np.random.Generator, sigma_px: float,
                  reflection_camera: int | None = None, hidden_y_m: float | None = None):
    """Stripe traces of light planes ``x = offset`` on :func:`height_field`, one frame each.

    Each camera's stripe is sampled on its image rows (``v`` exact, noise ``sigma_px`` on ``u``,
    ``cov_vv = 0`` as the detector reports). Optionally camera ``reflection_camera`` also sees a
    dimmer copy shifted by 15 px (rank 1), and only camera 0 sees the part ``y > hidden_y_m``.

    Returns
    -------
    table : pyarrow.Table
    """
    import pyarrow as pa

    from scanrig.laser.traces import SCHEMA

    cols = {f.name: [] for f in SCHEMA}
    y = np.linspace(-0.15, 0.15, 6000)
    for k, s in enumerate(offsets_m):
        curve = np.c_[np.full_like(y, s), y, height_field(np.full_like(y, s), y)]
        for i, cam in enumerate(rig.cameras):
            keep = np.ones(len(y), bool) if hidden_y_m is None or i == 0 else y <= hidden_y_m
            q = cam.project(curve[keep])
            order = np.argsort(q[:, 1])
            if np.any(np.diff(q[order, 1]) == 0):
                raise ValueError("stripe not monotonic in v")
            rows = np.arange(np.ceil(q[:, 1].min()), np.floor(q[:, 1].max()) + 1)
            rows = rows[(rows >= 0) & (rows <= HEIGHT - 1)]
            u = np.interp(rows, q[order, 1], q[order, 0])
            inside = (u >= 0) & (u <= WIDTH - 1)
            rows, u = rows[inside], u[inside]
            pieces = [(u + rng.normal(0.0, sigma_px, len(u)), 0)]
            if reflection_camera == i:
                pieces.append((u + 15.0 + rng.normal(0.0, sigma_px, len(u)), 1))
            for uu, rank in pieces:
                n = len(uu)
                cols["camera"] += [cam.name] * n
                cols["frame"] += [f"s{k:03d}"] * n
                cols["kind"] += ["stripe"] * n
                for name, value in (("u", uu), ("v", rows), ("sigma_px", np.full(n, sigma_px)),
                                    ("peak", np.full(n, 150.0)), ("width_px", np.full(n, 1.5)),
                                    ("snr", np.full(n, 60.0)), ("rank", np.full(n, rank)),
                                    ("cov_uu", np.full(n, sigma_px**2)), ("cov_uv", np.zeros(n)),
                                    ("cov_vv", np.zeros(n)), ("line", rows.astype(np.int32)),
                                    ("saturated", np.zeros(n, bool))):
                    cols[name] += list(value)
    return pa.Table.from_pydict(cols, schema=SCHEMA)


def plane_curve(normal, offset_m: float, t_range=(-0.15, 0.15), n: int = 6000, half_m: float = 0.15):
    """Where the plane ``normal · p = offset_m`` meets :func:`height_field`, sampled along it.

    The curve is parametrised by ``t`` along the plane's horizontal direction; the height is
    solved by fixed-point iteration (the surface is gentle). Points outside the surface patch
    ``|x|, |y| <= half_m`` are dropped.

    Returns
    -------
    ndarray of shape (M, 3)
        Points of the curve in order, metres.
    """
    nrm = np.asarray(normal, np.float64)
    nrm = nrm / np.linalg.norm(nrm)
    u = np.cross(nrm, [0.0, 0.0, 1.0])
    u /= np.linalg.norm(u)
    w = np.cross(nrm, u)
    base = offset_m * nrm + np.linspace(*t_range, n)[:, None] * u
    lam = np.zeros(n)
    for _ in range(30):
        p = base + lam[:, None] * w
        lam = lam + (height_field(p[:, 0], p[:, 1]) - p[:, 2]) / w[2]
    p = base + lam[:, None] * w
    inside = np.all(np.abs(p[:, :2]) <= half_m, axis=1)
    return p[inside]


def curve_traces(rig: Rig, curves, rng: np.random.Generator, sigma_px: float):
    """Stripe traces of 3-D curves as the stripe detector reports them, with ranks by brightness.

    Parameters
    ----------
    rig : Rig
    curves : list of (frame, points (M, 3), peak)
        Lit curves on the surface: the light plane's stripe, and secondary reflections (curves
        on the surface that are *not* on the light plane; every camera that looks there sees
        them, consistently in 3-D). ``peak`` orders the candidates of a scan line (rank 0 =
        brightest).
    rng : numpy.random.Generator
    sigma_px : float
        Noise of the measured coordinate along the scan line.

    Each camera scans rows where its image of the curve runs more vertically than horizontally
    (``v`` exact, noise on ``u``, ``cov_vv = 0``) and columns otherwise, like the detector.

    Returns
    -------
    table : pyarrow.Table
    """
    import pyarrow as pa

    from scanrig.laser.traces import SCHEMA

    per_line = {}  # (camera, frame, rows?, line) -> list of (measured, peak)
    for frame, points, peak in curves:
        for cam in rig.cameras:
            q = cam.project(points)
            q = q[np.all(np.isfinite(q), axis=1)]
            if len(q) < 2:
                continue
            rows = abs(q[-1, 1] - q[0, 1]) >= abs(q[-1, 0] - q[0, 0])
            along, across = (q[:, 1], q[:, 0]) if rows else (q[:, 0], q[:, 1])
            order = np.argsort(along)
            if np.any(np.diff(along[order]) == 0) or not (np.all(np.diff(along) > 0) or np.all(np.diff(along) < 0)):
                raise ValueError(f"curve not monotonic along the scan lines of {cam.name}")
            lines = np.arange(np.ceil(along.min()), np.floor(along.max()) + 1)
            size_along, size_across = (HEIGHT, WIDTH) if rows else (WIDTH, HEIGHT)
            lines = lines[(lines >= 0) & (lines <= size_along - 1)]
            pos = np.interp(lines, along[order], across[order])
            inside = (pos >= 0) & (pos <= size_across - 1)
            lines, pos = lines[inside], pos[inside] + rng.normal(0.0, sigma_px, inside.sum())
            for line, x in zip(lines, pos):
                per_line.setdefault((cam.name, frame, rows, int(line)), []).append((x, peak))
    cols = {f.name: [] for f in SCHEMA}
    for (camera, frame, rows, line), cands in per_line.items():
        cands.sort(key=lambda c: -c[1])
        for rank, (x, peak) in enumerate(cands):
            u, v = (x, float(line)) if rows else (float(line), x)
            values = dict(camera=camera, frame=frame, kind="stripe", u=u, v=v, sigma_px=sigma_px, peak=peak,
                          width_px=1.5, snr=60.0, rank=rank, cov_uu=sigma_px**2 if rows else 0.0, cov_uv=0.0,
                          cov_vv=0.0 if rows else sigma_px**2, line=line, saturated=False)
            for name, value in values.items():
                cols[name].append(value)
    return pa.Table.from_pydict(cols, schema=SCHEMA)
