"""The camera sensor: radiance to electrons, lens blur, shot and read noise, quantisation.

Radiometry (thin lens, object far compared with the focal length): a pixel of pitch ``a``
behind a lens of f-number ``N`` looking at radiance ``L`` (W/(m²·sr)) collects
``L * pi / (4 N²) * a² * t_exp`` joules; with quantum efficiency ``qe`` and photon energy
``h c / lambda`` that is :attr:`Sensor.e_per_radiance` electrons per unit radiance.

Noise: electrons are Poisson (shot noise), plus Gaussian read noise ``read_noise_e``; the result
is clipped at the full well, divided by the gain (e-/DN), offset by the black level, rounded
and clipped to the bit depth. The variance of a flat region is therefore, in DN²::

    var = (signal_e + read_noise_e²) / gain² + 1/12          (the last term from rounding)

Speed: laser frames differ from the laser-free background only in a small window. Outside it,
each frame's noise is ``std_map * z`` where ``z`` is a slice of a per-camera bank of standard
normals taken at a random offset (the Gaussian limit of Poisson, with the exact mean and
variance); inside the window the noise is drawn exactly (Poisson + Gaussian). Every frame thus
sees independent noise of the right variance everywhere (two frames share a bank value at a
pixel only if their random offsets coincide).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from scanrig.errors import InputError

_PLANCK_J_S = 6.62607015e-34
_LIGHT_M_S = 299792458.0
#: Extra bank length beyond one frame: the number of distinct random offsets.
_BANK_OFFSETS = 1 << 16


@dataclass(frozen=True)
class Sensor:
    """Exposure, optics and noise of a camera.

    Parameters
    ----------
    exposure_s : float
        Exposure time, seconds.
    f_number : float
        Lens f-number.
    pixel_pitch_m : float
        Pixel size, metres.
    qe : float
        Quantum efficiency at the laser wavelength.
    wavelength_m : float
        Wavelength used for the photon energy, metres.
    full_well_e : float
        Saturation charge, electrons.
    gain_e_per_dn : float
        Electrons per digital number.
    read_noise_e : float
        Read noise, electrons RMS.
    bit_depth : {8, 12, 16}
        Output bit depth (12-bit values are stored in 16-bit images, unscaled).
    black_level_dn : float
        Offset added before quantisation, DN.
    psf_sigma_px : float
        Gaussian lens blur, 1-σ in pixels (0 = none).
    supersampling : int
        Sub-pixel samples per axis where integration matters (edges, laser traces).
    speckle_contrast : float
        Laser speckle contrast in [0, 1] (0 = none).
    speckle_grain_px : float
        Mean speckle size, pixels.
    """

    exposure_s: float = 2e-4
    f_number: float = 8.0
    pixel_pitch_m: float = 4.8e-6
    qe: float = 0.4
    wavelength_m: float = 650e-9
    full_well_e: float = 10000.0
    gain_e_per_dn: float = 10000.0 / 255.0
    read_noise_e: float = 12.0
    bit_depth: int = 8
    black_level_dn: float = 2.0
    psf_sigma_px: float = 0.6
    supersampling: int = 4
    speckle_contrast: float = 0.0
    speckle_grain_px: float = 1.5

    def __post_init__(self):
        for name in ("exposure_s", "f_number", "pixel_pitch_m", "qe", "wavelength_m", "full_well_e", "gain_e_per_dn"):
            if not getattr(self, name) > 0:
                raise InputError(f"sensor {name} must be positive, got {getattr(self, name)!r}")
        for name in ("read_noise_e", "black_level_dn", "psf_sigma_px"):
            if not getattr(self, name) >= 0:
                raise InputError(f"sensor {name} must be >= 0, got {getattr(self, name)!r}")
        if self.bit_depth not in (8, 12, 16):
            raise InputError(f"sensor bit_depth must be 8, 12 or 16, got {self.bit_depth!r}")
        if not (isinstance(self.supersampling, int) and 1 <= self.supersampling <= 32):
            raise InputError(f"sensor supersampling must be an integer in [1, 32], got {self.supersampling!r}")
        if not 0 <= self.speckle_contrast <= 1 or not self.speckle_grain_px > 0:
            raise InputError("sensor speckle_contrast must be in [0, 1] and speckle_grain_px positive")

    @property
    def e_per_radiance(self) -> float:
        """Electrons collected per unit scene radiance, e- / (W m⁻² sr⁻¹)."""
        photon_j = _PLANCK_J_S * _LIGHT_M_S / self.wavelength_m
        etendue = np.pi / (4 * self.f_number**2) * self.pixel_pitch_m**2
        return float(etendue * self.exposure_s * self.qe / photon_j)

    @property
    def max_dn(self) -> int:
        return (1 << self.bit_depth) - 1

    @property
    def dtype(self):
        return np.uint8 if self.bit_depth == 8 else np.uint16

    def with_exposure(self, exposure_s: float) -> Sensor:
        return replace(self, exposure_s=exposure_s)

    def noise_var_dn2(self, signal_e: np.ndarray) -> np.ndarray:
        """Model variance of the output in DN² for a noise-free signal in electrons (unsaturated)."""
        return (np.asarray(signal_e) + self.read_noise_e**2) / self.gain_e_per_dn**2 + 1.0 / 12.0

    # --- image formation ----------------------------------------------------------------------
    def expose(self, signal_e: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Exact noise: Poisson shot noise, Gaussian read noise, full well, gain, rounding, clipping.

        Parameters
        ----------
        signal_e : ndarray, float
            Noise-free expected electrons per pixel (after blur).
        rng : numpy.random.Generator

        Returns
        -------
        ndarray of :attr:`dtype`
            Digital numbers.
        """
        e = rng.poisson(np.maximum(signal_e, 0.0)).astype(np.float64)
        e += rng.normal(0.0, self.read_noise_e, size=e.shape)
        return self._to_dn(e)

    def expose_clean(self, signal_e: np.ndarray) -> np.ndarray:
        """The noise-free digital image (rounding and saturation only)."""
        return self._to_dn(np.asarray(signal_e, dtype=np.float64))

    def _to_dn(self, e: np.ndarray) -> np.ndarray:
        dn = np.minimum(e, self.full_well_e) / self.gain_e_per_dn + self.black_level_dn
        return np.clip(np.rint(dn), 0, self.max_dn).astype(self.dtype)


class NoiseField:
    """Fast full-frame noise for one camera's fixed background (see the module notes).

    Parameters
    ----------
    sensor : Sensor
    background_e : ndarray of shape (H, W)
        Noise-free background electrons (after blur).
    rng : numpy.random.Generator
        Draws the bank of standard normals (once).
    """

    def __init__(self, sensor: Sensor, background_e: np.ndarray, rng: np.random.Generator):
        self.sensor = sensor
        self.shape = background_e.shape
        g = sensor.gain_e_per_dn
        clipped = np.minimum(background_e, sensor.full_well_e)
        self.mean_dn = (clipped / g + sensor.black_level_dn).astype(np.float32).ravel()
        self.std_dn = (np.sqrt(np.maximum(clipped, 0.0) + sensor.read_noise_e**2) / g).astype(np.float32).ravel()
        self.high_dn = float(min(sensor.max_dn, np.floor(sensor.full_well_e / g + sensor.black_level_dn + 0.5)))
        self._bank = rng.standard_normal(self.mean_dn.size + _BANK_OFFSETS, dtype=np.float32)

    def frame(self, rng: np.random.Generator) -> np.ndarray:
        """A noisy laser-free frame, shape (H, W), the sensor's dtype."""
        off = int(rng.integers(0, _BANK_OFFSETS))
        buf = np.multiply(self.std_dn, self._bank[off:off + self.mean_dn.size])
        buf += self.mean_dn
        np.rint(buf, out=buf)
        np.clip(buf, 0.0, self.high_dn, out=buf)
        return buf.astype(self.sensor.dtype).reshape(self.shape)
