"""Surface materials: Lambertian paint with a procedural albedo texture, and shiny metal.

A material reflects incident irradiance ``E`` (W/m²) as radiance (W/(m²·sr)) towards a viewer::

    L = E * (albedo(x) / pi  +  specular * lobe(alpha))

``lobe`` is a normalised Gaussian in the angle ``alpha`` between the mirror direction of the
incoming light and the direction to the viewer, ``exp(-alpha² / (2 s²)) / (2 pi s²)`` per
steradian with ``s = roughness_rad`` (it integrates to 1 over the hemisphere for small ``s``).
The same lobe sends a fraction ``specular`` of a laser beam on to other surfaces, where it makes
secondary traces (see :mod:`scanrig.sim.laser`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from scanrig.errors import InputError

#: Material kinds; ``dark`` is matte with a low default albedo.
KINDS = ("matte", "dark", "metal")
_DEFAULT_ALBEDO = {"matte": 0.7, "dark": 0.05, "metal": 0.08}
#: Number of plane waves summed by the procedural texture.
_N_WAVES = 6


@dataclass(frozen=True)
class Material:
    """Reflectance of one surface.

    Parameters
    ----------
    name : str
        Name used by scene files.
    kind : {"matte", "dark", "metal"}
        Matte and dark are Lambertian; metal adds a specular lobe.
    albedo : float, optional
        Mean diffuse (Lambertian) reflectance in [0, 1]; default by kind (0.7, 0.05, 0.08).
    texture_amplitude : float
        Relative albedo modulation of the procedural texture, in [0, 1) (0 = uniform).
    texture_scale_m : float
        Typical wavelength of the texture, metres.
    texture_seed : int
        Seed of the texture's random wave directions and phases (part of the scene, not of a run).
    specular : float
        Fraction of incident light reflected into the specular lobe (metal only), in [0, 1].
    roughness_rad : float
        1-σ angular width of the specular lobe, radians (metal only).
    """

    name: str
    kind: str = "matte"
    albedo: float | None = None
    texture_amplitude: float = 0.0
    texture_scale_m: float = 0.02
    texture_seed: int = 0
    specular: float = 0.0
    roughness_rad: float = 0.05
    _waves: tuple = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        if self.kind not in KINDS:
            raise InputError(f"material {self.name!r}: kind must be one of {KINDS}, got {self.kind!r}")
        albedo = _DEFAULT_ALBEDO[self.kind] if self.albedo is None else float(self.albedo)
        object.__setattr__(self, "albedo", albedo)
        _check_range(self.name, "albedo", albedo, 0.0, 1.0)
        _check_range(self.name, "texture_amplitude", self.texture_amplitude, 0.0, 0.999)
        _check_range(self.name, "specular", self.specular, 0.0, 1.0)
        if self.kind != "metal" and self.specular > 0:
            raise InputError(f"material {self.name!r}: specular must be 0 for kind {self.kind!r} (use kind = \"metal\")")
        if albedo + self.specular > 1.0:
            raise InputError(f"material {self.name!r}: albedo + specular must be <= 1 (energy), got {albedo + self.specular}")
        if not self.texture_scale_m > 0 or not self.roughness_rad > 0:
            raise InputError(f"material {self.name!r}: texture_scale_m and roughness_rad must be positive")
        rng = np.random.default_rng(self.texture_seed)
        dirs = rng.normal(size=(_N_WAVES, 3))
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        k = dirs * (2 * np.pi / self.texture_scale_m) * rng.uniform(0.5, 1.5, size=(_N_WAVES, 1))
        object.__setattr__(self, "_waves", (k, rng.uniform(0, 2 * np.pi, _N_WAVES)))

    @property
    def is_shiny(self) -> bool:
        """True when the material has a specular lobe."""
        return self.specular > 0

    def albedo_at(self, p_world: np.ndarray) -> np.ndarray:
        """Diffuse albedo at surface points.

        Parameters
        ----------
        p_world : ndarray of shape (N, 3)
            Points on the surface, world frame, metres.

        Returns
        -------
        ndarray of shape (N,)
            Albedo in [0, 1].
        """
        if self.texture_amplitude == 0:
            return np.full(len(p_world), self.albedo)
        k, phase = self._waves
        texture = np.sin(p_world @ k.T + phase).sum(axis=1) * np.sqrt(2.0 / _N_WAVES)
        return np.clip(self.albedo * (1.0 + self.texture_amplitude * np.tanh(texture)), 0.0, 1.0)


def specular_lobe(cos_alpha: np.ndarray, roughness_rad: np.ndarray) -> np.ndarray:
    """Gaussian specular lobe per steradian.

    Parameters
    ----------
    cos_alpha : ndarray of shape (N,)
        Cosine of the angle between the mirror direction and the direction to the viewer.
    roughness_rad : ndarray of shape (N,) or float
        1-σ lobe width, radians.

    Returns
    -------
    ndarray of shape (N,)
        ``exp(-alpha² / (2 s²)) / (2 pi s²)``, sr⁻¹.
    """
    alpha = np.arccos(np.clip(cos_alpha, -1.0, 1.0))
    s2 = np.asarray(roughness_rad, dtype=np.float64) ** 2
    return np.exp(-0.5 * alpha * alpha / s2) / (2 * np.pi * s2)


def _check_range(name: str, field_name: str, value: float, lo: float, hi: float) -> None:
    if not lo <= value <= hi:
        raise InputError(f"material {name!r}: {field_name} must be in [{lo}, {hi}], got {value!r}")
