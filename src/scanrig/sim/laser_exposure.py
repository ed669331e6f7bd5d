"""Laser power from a wanted exposure: how far past full scale a camera sees the laser.

An operator exposes a line laser so that the stripe is visible on dark parts, which puts it far
past full scale on white ones. :func:`nominal_peak_e_per_W` gives the peak electrons per watt of
laser power, in the laser channel, on a white Lambertian surface (albedo 1) at the scene centre
facing both the laser head and a camera of the scene's rig; :func:`overexposed_laser` scales the
laser's powers so that this peak is ``overexposure`` times the sensor's full well.

The peak counts the beam's Gaussian profile across the sheet (or spot) as seen by a camera
(``w / 2 · fx / distance`` pixels, 1 σ), blurred by the lens PSF and averaged over the pixel (a
box of variance 1/12 px²): the image's peak is the optical peak times ``σ_beam / σ_total`` per
blurred axis (one for a stripe, two for a spot). Real peaks differ with the distance from the head
and the cameras, the angles of incidence and view, the albedo and the sub-surface halo.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from scanrig.errors import InputError
from scanrig.sim.laser import LaserSpec
from scanrig.sim.rigs import RigSpec
from scanrig.sim.sensor import Sensor


def nominal_peak_e_per_W(laser: LaserSpec, sensor: Sensor, rig: RigSpec, center_m, mode: str) -> float:
    """Peak laser electrons per watt of the laser's power, on white paper at the scene centre.

    Parameters
    ----------
    laser : LaserSpec
    sensor : Sensor
    rig : RigSpec
        Camera distance and focal length (the beam's width in pixels).
    center_m : (3,) float
        Scene centre, world metres.
    mode : {"spot", "stripe"}

    Returns
    -------
    float
        Electrons per watt, e-/W.
    """
    r_m = float(np.linalg.norm(np.asarray(laser.head_m, dtype=np.float64) - np.asarray(center_m, dtype=np.float64)))
    w_m = laser.waist_m * math.sqrt(1.0 + ((r_m - laser.focus_m) / laser.rayleigh_m) ** 2)
    sigma_beam_px = w_m / 2 * rig.fx_px / rig.distance_m
    keep = sigma_beam_px / math.sqrt(sigma_beam_px**2 + sensor.psf_sigma_px**2 + 1.0 / 12.0)
    if mode == "stripe":
        irradiance_per_W = math.sqrt(2 / math.pi) / (2 * math.radians(laser.fan_half_angle_deg) * r_m * w_m) * keep
    elif mode == "spot":
        irradiance_per_W = 2 / (math.pi * w_m**2) * keep**2
    else:
        raise InputError(f"mode must be 'spot' or 'stripe', got {mode!r}")
    return irradiance_per_W / math.pi * sensor.e_per_radiance


def overexposed_laser(laser: LaserSpec, sensor: Sensor, rig: RigSpec, center_m, overexposure: float) -> LaserSpec:
    """The laser with ``power_W`` and ``stripe_power_W`` set so that its nominal peak
    (:func:`nominal_peak_e_per_W`) is ``overexposure`` times the full well.

    Parameters
    ----------
    laser, sensor, rig, center_m
        As :func:`nominal_peak_e_per_W`.
    overexposure : float
        Wanted peak over full scale (> 0; 1 = just full scale, 10 = ten times past it).

    Returns
    -------
    LaserSpec
    """
    if not (isinstance(overexposure, (int, float)) and 0 < overexposure < math.inf):
        raise InputError(f"laser_overexposure must be a positive number, got {overexposure!r}")
    peak_e = overexposure * sensor.full_well_e
    return replace(laser, power_W=peak_e / nominal_peak_e_per_W(laser, sensor, rig, center_m, "spot"),
                   stripe_power_W=peak_e / nominal_peak_e_per_W(laser, sensor, rig, center_m, "stripe"))
