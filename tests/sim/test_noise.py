"""Noise is right: measured per-pixel noise of flat regions matches the shot + read model."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from scanrig.sim.laser import BeamPose, trace_laser
from scanrig.sim.render import CameraView
from scanrig.sim.sensor import NoiseField, Sensor

from .conftest import plane_scene, small_rig

#: Acceptance: measured variance within 5 % of the model. With N independent samples the
#: relative standard error of a variance is sqrt(2 / N); the tests use N >= 60 000, i.e. < 0.6 %.
NOISE_REL_TOL = 0.05


def _flat_signal(sensor: Sensor, level_e: float, shape=(64, 64)) -> np.ndarray:
    return np.full(shape, level_e, dtype=np.float32)


@pytest.mark.parametrize("bit_depth, level_e", [(12, 3000.0), (12, 200.0), (16, 6000.0), (8, 5000.0)])
def test_exact_noise_matches_model(rng, bit_depth, level_e):
    gain = 10000.0 / ((1 << bit_depth) - 1)
    sensor = Sensor(bit_depth=bit_depth, gain_e_per_dn=gain, read_noise_e=10.0)
    frames = np.stack([sensor.expose(_flat_signal(sensor, level_e), rng) for _ in range(16)]).astype(np.float64)
    measured = frames.var(axis=0, ddof=1).mean()
    model = sensor.noise_var_dn2(level_e)
    assert abs(measured / model - 1) < NOISE_REL_TOL, (measured, model)
    assert abs(frames.mean() - (level_e / gain + sensor.black_level_dn)) < 0.05 * np.sqrt(model)


@pytest.mark.parametrize("bit_depth", [8, 12])
def test_fast_background_noise_matches_model_and_is_independent(rng, bit_depth):
    gain = 10000.0 / ((1 << bit_depth) - 1)
    sensor = Sensor(bit_depth=bit_depth, gain_e_per_dn=gain, read_noise_e=10.0)
    level_e = 2500.0
    field = NoiseField(sensor, _flat_signal(sensor, level_e, (128, 128)), rng)
    frames = np.stack([field.frame(rng) for _ in range(8)]).astype(np.float64)
    measured = frames.var(axis=0, ddof=1).mean()
    model = sensor.noise_var_dn2(level_e)
    assert abs(measured / model - 1) < NOISE_REL_TOL, (measured, model)
    # successive frames are uncorrelated pixel by pixel (|r| of 16k pairs has sd ~ 0.008)
    a, b = frames[0] - frames[0].mean(), frames[1] - frames[1].mean()
    assert abs((a * b).mean() / np.sqrt((a * a).mean() * (b * b).mean())) < 0.04


def test_rendered_frames_have_model_noise_in_flat_regions(rng):
    """Whole pipeline: a uniformly lit matte plane; noise measured where the background is flat,
    both outside and inside the laser window, against the model at each pixel's clean signal."""
    sensor = Sensor(bit_depth=12, gain_e_per_dn=10000.0 / 4095, read_noise_e=10.0, psf_sigma_px=0.0)
    scene = plane_scene(sensor=sensor)
    cam = small_rig(1).cameras[0]
    view = CameraView(cam, scene, rng=rng)
    head = np.asarray(scene.laser.head_m)
    wide = replace(scene.laser, waist_m=3e-3)        # a big spot gives a big window to measure in
    trace = trace_laser(BeamPose(head, -head / np.linalg.norm(head)), wide, scene)
    clean = view.clean_frame_e(trace)
    frames = np.stack([view.frame(trace, rng) for _ in range(24)]).astype(np.float64)
    var = frames.var(axis=0, ddof=1)
    model = sensor.noise_var_dn2(clean)
    window = view.laser_window(trace)
    in_window = np.zeros(clean.shape, dtype=bool)
    in_window[window.slices] = True
    lit = clean > 300.0
    for region in (lit & ~in_window, lit & in_window):
        # >= 300 pixels x 23 degrees of freedom: standard error of the ratio <= 1.7 %
        assert region.sum() >= 300
        ratio = var[region].mean() / model[region].mean()
        assert abs(ratio - 1) < NOISE_REL_TOL, ratio


@pytest.mark.parametrize("contrast", [0.3, 1.0])
def test_speckle_has_unit_mean_and_configured_contrast(rng, contrast):
    from scanrig.sim.render import _speckle

    field = _speckle((256, 256), contrast, 2.0, rng).astype(np.float64)
    # ~256² / (grain area ~ 2²) ≈ 16 000 independent grains: mean and contrast known to ~1-2 %
    assert abs(field.mean() - 1) < 0.03
    assert abs(field.std() / field.mean() - contrast) < 0.1 * contrast
