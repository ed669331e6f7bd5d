"""Colour cameras: how an RGB sensor sees a red line laser and the white-lit scene.

Image formation, per frame (all in electrons until the sensor's conversion):

1. Sub-surface halo: paper, plastic, marble and skin re-emit part of the laser light a few pixels
   from where it entered. ``laser_halo = (1 - f) * laser_e + f * (laser_e * K)``, with ``K`` a
   normalised exponential kernel ``exp(-r / halo_radius_px)`` (energy conserving, away from the
   image border).
2. Channel responses: ``e_c = ambient_rgb[c] * scene_e + laser_rgb[c] * laser_halo``. The green and
   blue filters of a Bayer sensor pass a few per cent to ~15 % of red laser light, so an
   over-exposed red stripe clips in R over a wide band and reaches full scale in G and B only at
   its centre.
3. Per channel, the sensor's exposure (:meth:`Sensor.expose` or :meth:`Sensor.expose_clean`):
   shot and read noise, full well, gain, black level, rounding, clipping.
4. Optionally an RGGB mosaic (each pixel keeps one channel) demosaiced by OpenCV, as a real
   colour camera delivers it.
5. Optionally a JPEG round trip with 4:2:0 chroma subsampling (colour at half resolution).

Sessions render colour frames through the same steps on the renderer's fast path
(:mod:`scanrig.sim.render`): :class:`ColourNoise` gives each channel's background noise, and
:func:`write_frame` stores a frame once, as ``.jpg`` or lossless ``.png``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scanrig.errors import InputError, ShapeError
from scanrig.io.atomic import write_bytes_atomic
from scanrig.io.session import write_image
from scanrig.sim.sensor import NoiseField, Sensor

#: The halo kernel is cut at this many ``halo_radius_px`` (an exponential keeps 0.3 % of its
#: energy beyond 8 radii; the kernel is renormalised after the cut).
HALO_TRUNCATE_RADII = 8.0


@dataclass(frozen=True)
class ColourResponse:
    """How a colour camera sees the laser and the scene (all set from the scene file).

    Parameters
    ----------
    laser_rgb : tuple of 3 float
        Response of the R, G, B pixels to the laser wavelength, relative to the laser channel
        (dimensionless, >= 0).
    ambient_rgb : tuple of 3 float
        Response of R, G, B to the scene's white light, relative to the grey render (>= 0).
    halo_fraction : float
        Fraction in [0, 1] of the laser light on the surface re-emitted into a sub-surface halo.
    halo_radius_px : float
        Scale of the exponential halo kernel, pixels (> 0).
    bayer : bool
        RGGB mosaic, then OpenCV demosaicing.
    jpeg_quality : int or None
        Store as JPEG at this quality (1 to 100) with 4:2:0 chroma subsampling; None = lossless.
        Needs an 8-bit sensor.
    white_balance : tuple of 3 float
        Gain of R, G, B applied to the digital numbers after the sensor clipped (and after
        demosaicing), rounded and clipped to the dtype again (> 0): a channel with a gain below 1
        clips below full scale, as webcams' white balance makes it.
    """

    laser_rgb: tuple[float, float, float] = (1.0, 0.06, 0.04)
    ambient_rgb: tuple[float, float, float] = (1.0, 1.0, 0.92)
    halo_fraction: float = 0.0
    halo_radius_px: float = 3.0
    bayer: bool = False
    jpeg_quality: int | None = None
    white_balance: tuple[float, float, float] = (1.0, 1.0, 1.0)

    def __post_init__(self):
        for name, positive, what in (("laser_rgb", False, "numbers >= 0, not all 0"),
                                     ("ambient_rgb", False, "numbers >= 0, not all 0"),
                                     ("white_balance", True, "gains > 0")):
            value = getattr(self, name)
            try:
                rgb = tuple(float(v) for v in value)
            except (TypeError, ValueError):
                rgb = ()
            if (len(rgb) != 3 or not all(math.isfinite(v) and v >= 0 for v in rgb)
                    or (min(rgb) if positive else max(rgb)) == 0):
                raise InputError(f"colour {name} must be 3 finite {what}, got {value!r}")
            object.__setattr__(self, name, rgb)
        if not (isinstance(self.halo_fraction, (int, float)) and 0 <= self.halo_fraction <= 1):
            raise InputError(f"colour halo_fraction must be in [0, 1], got {self.halo_fraction!r}")
        if not (isinstance(self.halo_radius_px, (int, float)) and 0 < self.halo_radius_px < math.inf):
            raise InputError(f"colour halo_radius_px must be a positive number of pixels, got {self.halo_radius_px!r}")
        if not isinstance(self.bayer, bool):
            raise InputError(f"colour bayer must be true or false, got {self.bayer!r}")
        q = self.jpeg_quality
        if q is not None and not (isinstance(q, int) and not isinstance(q, bool) and 1 <= q <= 100):
            raise InputError(f"colour jpeg_quality must be an integer in [1, 100] or absent, got {q!r}")

    @property
    def halo_pad_px(self) -> int:
        """Pixels the halo reaches beyond the laser light (0 without a halo)."""
        return halo_kernel_half_px(self.halo_radius_px) if self.halo_fraction > 0 else 0


def halo_kernel_half_px(radius_px: float) -> int:
    """Half-width of the truncated halo kernel, pixels."""
    return int(math.ceil(HALO_TRUNCATE_RADII * radius_px))


def halo_kernel(radius_px: float) -> np.ndarray:
    """The normalised exponential halo kernel ``exp(-r / radius_px)``.

    Returns
    -------
    ndarray of shape (2h + 1, 2h + 1), float32
        Sums to 1; ``h`` is :func:`halo_kernel_half_px`.
    """
    h = halo_kernel_half_px(radius_px)
    d = np.arange(-h, h + 1, dtype=np.float64)
    r = np.hypot(d[:, None], d[None, :])
    k = np.where(r <= h, np.exp(-r / radius_px), 0.0)
    return (k / k.sum()).astype(np.float32)


def subsurface_halo(laser_e: np.ndarray, response: ColourResponse) -> np.ndarray:
    """Spread the fraction ``halo_fraction`` of the laser light over the halo kernel.

    Parameters
    ----------
    laser_e : ndarray of shape (H, W)
        Laser electrons in the laser channel.
    response : ColourResponse

    Returns
    -------
    ndarray of shape (H, W), float32
        Same total energy away from the border (light spread past the border is lost).
    """
    laser = np.asarray(laser_e, dtype=np.float32)
    f = response.halo_fraction
    if f == 0:
        return laser
    import cv2

    spread = cv2.filter2D(laser, cv2.CV_32F, halo_kernel(response.halo_radius_px),
                          borderType=cv2.BORDER_CONSTANT)
    return (1.0 - f) * laser + f * spread


def channel_electrons(scene_e: np.ndarray, laser_e: np.ndarray, response: ColourResponse) -> np.ndarray:
    """Noise-free electrons per channel (halo included).

    Parameters
    ----------
    scene_e, laser_e : ndarray of shape (H, W)
        Scene electrons (white light, unit channel response) and laser electrons (laser channel,
        before the halo).
    response : ColourResponse

    Returns
    -------
    ndarray of shape (H, W, 3), float32
    """
    scene = np.asarray(scene_e, dtype=np.float32)
    laser = np.asarray(laser_e)
    if scene.ndim != 2 or laser.shape != scene.shape:
        raise ShapeError(f"colour_frame: scene_e and laser_e must be (H, W) of the same shape, "
                         f"got {scene.shape} and {laser.shape}")
    halo = subsurface_halo(laser, response)
    ambient = np.asarray(response.ambient_rgb, dtype=np.float32)
    beam = np.asarray(response.laser_rgb, dtype=np.float32)
    return scene[..., None] * ambient + halo[..., None] * beam


def bayer_demosaic(rgb: np.ndarray) -> np.ndarray:
    """Keep one channel per pixel in an RGGB mosaic, then demosaic with OpenCV (bilinear).

    Parameters
    ----------
    rgb : ndarray of shape (H, W, 3), uint8 or uint16

    Returns
    -------
    ndarray of shape (H, W, 3), same dtype, RGB order
    """
    import cv2

    mosaic = np.empty(rgb.shape[:2], dtype=rgb.dtype)
    mosaic[0::2, 0::2] = rgb[0::2, 0::2, 0]
    mosaic[0::2, 1::2] = rgb[0::2, 1::2, 1]
    mosaic[1::2, 0::2] = rgb[1::2, 0::2, 1]
    mosaic[1::2, 1::2] = rgb[1::2, 1::2, 2]
    return cv2.demosaicing(mosaic, cv2.COLOR_BayerRGGB2RGB)


def encode_jpeg(rgb: np.ndarray, quality: int) -> bytes:
    """The JPEG file (4:2:0 chroma subsampling) of an RGB uint8 image of shape (H, W, 3) at ``quality`` (1 to 100)."""
    import cv2

    params = [cv2.IMWRITE_JPEG_QUALITY, int(quality),
              cv2.IMWRITE_JPEG_SAMPLING_FACTOR, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_420]
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(rgb[..., ::-1]), params)
    if not ok:
        raise InputError(f"colour: OpenCV could not encode a JPEG of shape {rgb.shape}")
    return buf.tobytes()


def jpeg_round_trip(rgb: np.ndarray, quality: int) -> np.ndarray:
    """Encode as JPEG (:func:`encode_jpeg`) and decode again.

    Parameters
    ----------
    rgb : ndarray of shape (H, W, 3), uint8
    quality : int
        JPEG quality, 1 to 100.

    Returns
    -------
    ndarray of shape (H, W, 3), uint8, RGB order
    """
    import cv2

    buf = np.frombuffer(encode_jpeg(rgb, quality), dtype=np.uint8)
    return cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1].copy()


def sensor_rgb(scene_e: np.ndarray, laser_e: np.ndarray, sensor: Sensor, response: ColourResponse,
               rng: np.random.Generator | None) -> np.ndarray:
    """The image the camera delivers before storage: :func:`colour_frame` without the JPEG step.

    Parameters and returns as :func:`colour_frame`.
    """
    check_sensor(response, sensor)
    return processed(expose_rgb(channel_electrons(scene_e, laser_e, response), sensor, rng), response)


def check_sensor(response: ColourResponse, sensor: Sensor) -> None:
    """Raise :class:`InputError` if the sensor cannot store what the response asks (JPEG needs 8 bits)."""
    if response.jpeg_quality is not None and sensor.bit_depth != 8:
        raise InputError(f"colour jpeg_quality needs an 8-bit sensor, got bit_depth {sensor.bit_depth}")


def expose_rgb(electrons: np.ndarray, sensor: Sensor, rng: np.random.Generator | None) -> np.ndarray:
    """Each channel through the sensor (:meth:`Sensor.expose`, or :meth:`Sensor.expose_clean` when
    ``rng`` is None): (H, W, 3) electrons to (H, W, 3) digital numbers of the sensor's dtype."""
    expose = sensor.expose_clean if rng is None else (lambda e: sensor.expose(e, rng))
    return np.stack([expose(electrons[..., c]) for c in range(3)], axis=-1)


def processed(rgb: np.ndarray, response: ColourResponse) -> np.ndarray:
    """The camera's processing of the sensor's digital numbers ``rgb`` (H, W, 3): the Bayer mosaic
    and demosaicing when it has one, then the white balance (``rgb`` itself when neither applies)."""
    rgb = bayer_demosaic(rgb) if response.bayer else rgb
    if response.white_balance == (1.0, 1.0, 1.0):
        return rgb
    gain = np.asarray(response.white_balance, np.float32)
    full_scale = np.iinfo(rgb.dtype).max
    return np.clip(np.rint(rgb * gain), 0, full_scale).astype(rgb.dtype)


def stored(rgb: np.ndarray, response: ColourResponse) -> np.ndarray:
    """The image as read back from storage (the JPEG round trip when the camera stores JPEG)."""
    return rgb if response.jpeg_quality is None else jpeg_round_trip(rgb, response.jpeg_quality)


def colour_frame(scene_e: np.ndarray, laser_e: np.ndarray, sensor: Sensor, response: ColourResponse,
                 rng: np.random.Generator | None) -> np.ndarray:
    """Render what a colour camera records.

    Parameters
    ----------
    scene_e : ndarray of shape (H, W)
        Noise-free scene electrons under white light, unit channel response (after blur).
    laser_e : ndarray of shape (H, W)
        Noise-free laser electrons in the laser channel, before the halo (after blur).
    sensor : Sensor
        Noise, full well, gain, black level and bit depth, applied per channel.
    response : ColourResponse
    rng : numpy.random.Generator or None
        Draws the noise; None renders noise-free (rounding and saturation only).

    Returns
    -------
    ndarray of shape (H, W, 3), the sensor's dtype
        RGB image.
    """
    return stored(sensor_rgb(scene_e, laser_e, sensor, response, rng), response)


class ColourNoise:
    """Fast full-frame noise of a colour camera's fixed background: one
    :class:`~scanrig.sim.sensor.NoiseField` per channel, of the background times ``ambient_rgb``.

    Parameters
    ----------
    sensor : Sensor
    background_e : ndarray of shape (H, W)
        Noise-free grey background electrons (unit channel response, after blur).
    response : ColourResponse
    rng : numpy.random.Generator
        Draws the three banks of standard normals (once).
    """

    def __init__(self, sensor: Sensor, background_e: np.ndarray, response: ColourResponse,
                 rng: np.random.Generator):
        self.fields = [NoiseField(sensor, background_e * np.float32(a), rng) for a in response.ambient_rgb]

    def frame(self, rng: np.random.Generator) -> np.ndarray:
        """A noisy laser-free frame before demosaicing, shape (H, W, 3), the sensor's dtype."""
        return np.stack([field.frame(rng) for field in self.fields], axis=-1)


def still_frame(scene_e: np.ndarray, sensor: Sensor, response: ColourResponse | None,
                rng: np.random.Generator) -> np.ndarray:
    """A laser-free noisy frame before storage: grey (H, W) from :meth:`Sensor.expose` when
    ``response`` is None, else RGB (H, W, 3) from :func:`sensor_rgb` with no laser light."""
    if response is None:
        return sensor.expose(scene_e, rng)
    return sensor_rgb(scene_e, np.zeros_like(scene_e), sensor, response, rng)


def write_frame(path_stem: Path, image: np.ndarray, response: ColourResponse | None) -> Path:
    """Write a frame as the camera stores it: ``<stem>.jpg`` (encoded once, at the camera's
    quality) when it stores JPEG, else lossless ``<stem>.png``.

    Parameters
    ----------
    path_stem : Path
        File name without suffix; its folder must exist.
    image : ndarray
        Grey (H, W) or RGB (H, W, 3) as delivered by the sensor (:func:`sensor_rgb`), before storage.
    response : ColourResponse or None
        None for a grey camera.

    Returns
    -------
    Path
        The file written. Reading a JPEG back gives exactly :func:`stored` of ``image``.
    """
    path_stem = Path(path_stem)
    if response is None or response.jpeg_quality is None:
        path = path_stem.with_name(path_stem.name + ".png")
        write_image(path, image)
    else:
        path = path_stem.with_name(path_stem.name + ".jpg")
        write_bytes_atomic(path, encode_jpeg(image, response.jpeg_quality))
    return path
