"""Over-exposed red stripes on printed white paper, as a colour camera records them, with exact truth.

The scene is white paper with printed black dots; a red line laser, exposed several times past full
scale, crosses it slightly tilted. Pixel integration of the beam uses ``scipy.special.ndtr``
directly (independent of the estimator's code, see :mod:`tests.laser.synth`); the colour camera
(crosstalk, sub-surface halo, clipping, noise, Bayer demosaicing, JPEG 4:2:0) is the simulator's
:func:`scanrig.sim.colour.colour_frame`.
"""

from __future__ import annotations

import numpy as np

from scanrig.sim.colour import ColourResponse, colour_frame
from scanrig.sim.sensor import Sensor
from tests.laser.synth import integrated

#: Paper and ink albedo, and the paper's level in the red channel as a fraction of full scale
#: (real paper beside a red stripe: (164, 166, 153) of 255).
PAPER_ALBEDO, INK_ALBEDO, PAPER_LEVEL = 0.7, 0.05, 0.64
#: Beam width (1-σ along a row, px) and the stripe's slope (px of u per row).
BEAM_SIGMA_PX, SLOPE = 1.2, 0.15
#: The colour camera of the held-out set: crosstalk, a 3-px halo carrying 30 % of the light,
#: Bayer demosaicing and JPEG at quality 90.
RESPONSE = ColourResponse(laser_rgb=(1.0, 0.07, 0.05), ambient_rgb=(1.0, 1.0, 0.92), halo_fraction=0.3,
                          halo_radius_px=3.0, bayer=True, jpeg_quality=90)


def printed_dots(shape, rng: np.random.Generator, n_dots: int = 40) -> np.ndarray:
    """Albedo ``(H, W)`` of white paper with ``n_dots`` printed black dots of radius 6-25 px."""
    h, w = shape
    albedo = np.full(shape, PAPER_ALBEDO)
    vv, uu = np.mgrid[0:h, 0:w]
    for cv, cu, r in zip(rng.uniform(0, h, n_dots), rng.uniform(0, w, n_dots), rng.uniform(6, 25, n_dots)):
        albedo[(vv - cv) ** 2 + (uu - cu) ** 2 < r * r] = INK_ALBEDO
    return albedo


def stripe_frames(rng: np.random.Generator, shape=(480, 640), overexposure: float = 8.0,
                  response: ColourResponse = RESPONSE):
    """A laser-on frame, its laser-off frame and the true centre of the stripe on every row.

    Parameters
    ----------
    rng : numpy.random.Generator
        Dots, the stripe's position and the noise.
    shape : (H, W)
    overexposure : float
        Peak of the beam on paper in the laser channel, in units of full scale.
    response : ColourResponse

    Returns
    -------
    on, off : (H, W, 3) uint8 arrays
    centre_u : (H,) float array
        True centre of the beam on each row, px.
    """
    sensor = Sensor()
    albedo = printed_dots(shape, rng)
    centre_u = rng.uniform(0.35, 0.45) * shape[1] + SLOPE * np.arange(shape[0])
    on = _stripe_frame(centre_u, albedo, overexposure, sensor, response, rng)
    off = _stripe_frame(None, albedo, overexposure, sensor, response, rng)
    return on, off, centre_u


def stripe_sweep(rng: np.random.Generator, n_frames: int, shape=(480, 640), n_dots: int = 40,
                 overexposure: float = 8.0, response: ColourResponse = RESPONSE):
    """Laser-on frames of the stripe swept across the fixed scene (from 10 % to 90 % of the width,
    evenly), one laser-off frame, and each frame's true centres.

    Returns
    -------
    on : list of (H, W, 3) uint8 arrays
    off : (H, W, 3) uint8 array
    centre_u : list of (H,) float arrays
    """
    sensor = Sensor()
    albedo = printed_dots(shape, rng, n_dots)
    h, w = shape
    centre_u = [(0.1 + 0.8 * k / (n_frames - 1)) * w + SLOPE * np.arange(h) for k in range(n_frames)]
    on = [_stripe_frame(c, albedo, overexposure, sensor, response, rng) for c in centre_u]
    return on, _stripe_frame(None, albedo, overexposure, sensor, response, rng), centre_u


def _stripe_frame(centre_u, albedo, overexposure, sensor, response, rng):
    """The colour frame of the printed paper ``albedo`` (H, W) lit by the stripe through ``centre_u``
    (H,) px, or laser-off when it is None."""
    full_e = sensor.full_well_e
    scene_e = PAPER_LEVEL * full_e * albedo / PAPER_ALBEDO
    if centre_u is None:
        return colour_frame(scene_e, np.zeros(albedo.shape), sensor, response, rng)
    beam = integrated(np.arange(albedo.shape[1], dtype=float)[None, :], centre_u[:, None], BEAM_SIGMA_PX)
    return colour_frame(scene_e, overexposure * full_e * beam * albedo / PAPER_ALBEDO, sensor, response, rng)


def spot_frames(rng: np.random.Generator, shape=(480, 640), overexposure: float = 8.0,
                response: ColourResponse = RESPONSE, spacing_px: int = 60, sigma_px: float = 1.5):
    """A laser-on frame with a grid of over-exposed red spots, its laser-off frame and the true centres.

    Returns
    -------
    on, off : (H, W, 3) uint8 arrays
    centres : (n, 2) float array
        True ``(u, v)`` of the spots, px.
    """
    sensor = Sensor()
    full_e = sensor.full_well_e
    albedo = printed_dots(shape, rng)
    h, w = shape
    gv, gu = np.meshgrid(np.arange(spacing_px, h - spacing_px // 2, spacing_px),
                         np.arange(spacing_px, w - spacing_px // 2, spacing_px), indexing="ij")
    centres = np.stack([gu.ravel(), gv.ravel()], axis=1) + rng.uniform(-0.5, 0.5, (gu.size, 2))
    beam = np.zeros(shape)
    for u0, v0 in centres:  # a few dozen spots, each its own small patch
        rows, cols = np.arange(int(v0) - 12, int(v0) + 13), np.arange(int(u0) - 12, int(u0) + 13)
        beam[np.ix_(rows, cols)] += (integrated(rows.astype(float), v0, sigma_px)[:, None]
                                     * integrated(cols.astype(float), u0, sigma_px)[None, :])
    laser_e = overexposure * full_e * beam * albedo / PAPER_ALBEDO
    scene_e = PAPER_LEVEL * full_e * albedo / PAPER_ALBEDO
    on = colour_frame(scene_e, laser_e, sensor, response, rng)
    off = colour_frame(scene_e, np.zeros(shape), sensor, response, rng)
    return on, off, centres


def exposed(frame: np.ndarray, gain) -> np.ndarray:
    """``frame`` (uint8) as taken at ``gain`` (scalar, or one per channel) times the exposure: its DN
    times the gain, rounded, within 0-255, its clipped pixels (255) still clipped."""
    scaled = np.clip(np.rint(frame * np.asarray(gain, float)), 0, 255).astype(np.uint8)
    return np.where(frame == 255, frame, scaled)
