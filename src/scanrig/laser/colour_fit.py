"""Clipped stripes in colour frames: one centre from every channel that is not clipped.

A red line laser exposed past full scale clips the red channel over a band several beam-widths
wide. The green and blue filters pass a few per cent of red light (and a camera's colour matrix
may subtract it again), so those channels rise, or dip, by a scaled copy of the same profile and
peak at the beam's centre, where the red channel carries nothing. Both pieces of information are
used at once: along the scan line, channel ``c`` at pixel ``i`` is modelled as

    μ_ci = b_c + a_c · g_i(x0, s)

with ``g`` the unit-peak pixel-integrated Gaussian of :mod:`scanrig.laser.fit`, one centre
``x0`` and width ``s`` shared by the channels, and an amplitude ``a_c`` (signed, except the
laser channel's) and a background ``b_c`` of each. Pixels clipped in the frame or in the dark
frame are left out in that channel only; each channel is weighted by its own noise. A halo of
light scattered below the surface widens the profile symmetrically: it does not move the centre,
and where the model leaves a misfit on the flanks the reported σ grows
(:func:`scanrig.laser.fit.centre_misfit`).
"""

from __future__ import annotations

import numpy as np

from scanrig.laser.fit import MIN_PEAK_DN, MIN_WIDTH_PX, _edges, _profile, centre_misfit, fit_batch
from scanrig.laser.image import ColourFrames, estimate_noise

#: Parameter order of the colour model.
PARAMS = ("x0", "width", "a_r", "a_g", "a_b", "b_r", "b_g", "b_b")
#: Largest amplitude fitted, in units of the clip level (a laser 100 times past full scale).
_MAX_OVEREXPOSURE = 100.0
#: Widths tried for the start, pixels.
_START_WIDTHS = np.array([0.7, 1.0, 1.4, 2.0, 2.8, 4.0, 5.6, 8.0])


def channel_noise(colour: ColourFrames) -> np.ndarray:
    """Noise σ of each raw channel (of frame − dark with a dark frame), DN: ``(3,)``."""
    out = np.empty(3)
    for c in range(3):
        plane = colour.image[:, :, c]
        if colour.dark is not None:
            plane = plane.astype(np.float32) - colour.dark[:, :, c]
        out[c] = estimate_noise(plane)
    return out


def fit_clipped(colour: ColourFrames, rows: bool, line: np.ndarray, pos: np.ndarray, half: int,
                max_shift_px: float) -> dict[str, np.ndarray]:
    """Fit the colour model to clipped stripe candidates along their scan lines.

    Parameters
    ----------
    colour : ColourFrames
        The raw frames (signal coordinates).
    rows : bool
        Scan lines are rows (else columns).
    line, pos : (n,) int arrays
        Scan line and position of each candidate: the middle of its clipped run.
    half : int
        The window is ``pos ± half`` pixels along the line.
    max_shift_px : float or (n,) float array
        A fitted centre further than this from ``pos`` has converged elsewhere: dropped.

    Returns
    -------
    dict of (n_ok,) arrays
        ``index`` (into the input), ``centre`` (px along the line), ``var`` (px²), ``peak``
        (laser channel's amplitude, DN), ``width_px``, ``snr`` (peak over the laser channel's noise).
    """
    image, dark = (colour.image, colour.dark) if rows else (
        colour.image.transpose(1, 0, 2), None if colour.dark is None else colour.dark.transpose(1, 0, 2))
    n_pos = image.shape[1]
    offs = np.arange(-half, half + 1)
    idx = pos[:, None] + offs  # (n, W)
    inside = (idx >= 0) & (idx < n_pos)
    np.clip(idx, 0, n_pos - 1, out=idx)
    raw = image[line[:, None], idx]  # (n, W, 3)
    usable = inside[:, :, None] & (raw < colour.clip_level)
    y = raw.astype(np.float64)
    if dark is not None:
        raw_dark = dark[line[:, None], idx]
        usable &= raw_dark < colour.clip_level
        y -= raw_dark
    noise = channel_noise(colour)
    # candidate-minor stacks, channel-major pixels: (3 W, n)
    y_minor = np.ascontiguousarray(y.transpose(2, 1, 0).reshape(-1, line.size))
    mask = np.ascontiguousarray(usable.transpose(2, 1, 0).reshape(-1, line.size))
    laser = colour.laser_channel
    p0 = _start(y, usable, offs, noise, laser)
    lower = np.full(8, -np.inf)
    upper = np.full(8, np.inf)
    lower[:2], upper[:2] = (-half, MIN_WIDTH_PX), (half, half / 2.0)
    lower[2:5], upper[2:5] = -_MAX_OVEREXPOSURE * colour.clip_level, _MAX_OVEREXPOSURE * colour.clip_level
    lower[2 + laser] = MIN_PEAK_DN
    whitened = y_minor / np.repeat(noise, offs.size)[:, None]
    res = fit_batch(_model(offs.astype(float), noise), whitened, mask, p0, lower, upper, minor=True)
    p = res.params
    var = res.info_inv[:, 0, 0].copy()
    good = np.isfinite(var)
    if good.any():  # whitened pixels: unit variance where fitted
        jac = res.jac.transpose(2, 1, 0)[..., good]
        var[good] *= centre_misfit(jac, res.info_inv[good], res.residuals.T[:, good],
                                   mask[:, good].astype(float), res.dof[good], (0,))
    ok = np.isfinite(var) & (np.abs(p[:, 0]) <= max_shift_px) & (res.dof > 0)
    peak = p[:, 2 + laser]
    out = {"index": np.arange(line.size), "centre": pos + p[:, 0], "var": var, "peak": peak,
           "width_px": p[:, 1], "snr": peak / noise[laser]}
    return {k: a[ok] for k, a in out.items()}


def _model(x: np.ndarray, noise: np.ndarray):
    """The colour model for :func:`scanrig.laser.fit.fit_batch` (``minor``), whitened by each
    channel's noise: ``p (8, n)`` -> ``mu (3 W, n)``, ``jac (8, 3 W, n)``."""
    edges = _edges(x)
    w = x.size
    inv = 1.0 / noise

    def model(p):
        n = p.shape[1]
        prof = np.empty((3, w, n))
        _profile(edges, p[0], p[1], prof)  # g, dg/dx0, dg/ds
        jac = np.zeros((8, 3, w, n))
        mu = np.empty((3, w, n))
        for c in range(3):  # three channels: a loop over a fixed axis of length 3, not over data
            a = p[2 + c] * inv[c]
            jac[0, c] = prof[1] * a
            jac[1, c] = prof[2] * a
            jac[2 + c, c] = prof[0] * inv[c]
            jac[5 + c, c] = inv[c]
            mu[c] = prof[0] * a + p[5 + c] * inv[c]
        return mu.reshape(3 * w, n), jac.reshape(8, 3 * w, n)

    return model


def _start(y: np.ndarray, usable: np.ndarray, offs: np.ndarray, noise: np.ndarray, laser: int) -> np.ndarray:
    """Start values ``(n, 8)``: centre 0 (the middle of the clipped run), the best of a few
    trial widths, and each channel's amplitude and background solved linearly for it from that
    channel's usable pixels (``y (n, W, 3)``, ``usable (n, W, 3)``)."""
    g = np.exp(-0.5 * (offs[None, :] / _START_WIDTHS[:, None]) ** 2)  # (k, W)
    w = usable.transpose(0, 2, 1)[:, :, None, :].astype(float)  # (n, 3, 1, W)
    yy = y.transpose(0, 2, 1)[:, :, None, :]  # (n, 3, 1, W)
    s_w, s_g, s_y = w.sum(-1), (w * g).sum(-1), (w * yy).sum(-1)  # (n, 3, k)
    s_gg, s_gy = (w * g * g).sum(-1), (w * g * yy).sum(-1)
    det = s_w * s_gg - s_g**2
    solvable = det > 1e-9 * np.maximum(s_w * s_gg, 1e-300)  # else the channel has no usable flank: 0
    with np.errstate(divide="ignore", invalid="ignore"):
        amp = np.where(solvable, (s_w * s_gy - s_g * s_y) / np.where(solvable, det, 1.0), 0.0)
        bg = np.where(s_w > 0, (s_y - amp * s_g) / np.maximum(s_w, 1e-300), 0.0)
    resid = (w * (yy - amp[..., None] * g - bg[..., None]) ** 2).sum(-1) / noise[None, :, None] ** 2
    best = np.argmin(resid.sum(axis=1), axis=1)  # (n,)
    pick = np.arange(y.shape[0])
    a, b = amp[pick, :, best], bg[pick, :, best]  # (n, 3)
    a[:, laser] = np.maximum(a[:, laser], 1.0)
    return np.concatenate([np.zeros((y.shape[0], 1)), _START_WIDTHS[best, None], a, b], axis=1)
