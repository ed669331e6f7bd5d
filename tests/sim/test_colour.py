"""Colour cameras: crosstalk, clipping, sub-surface halo, Bayer, JPEG and noise of `colour_frame`."""

from __future__ import annotations

import tomllib
from dataclasses import replace

import numpy as np
import pytest

from scanrig.errors import FileFormatError, InputError, ShapeError
from scanrig.io.session import read_image
from scanrig.sim import load_scene
from scanrig.sim.colour import (ColourResponse, channel_electrons, colour_frame, halo_kernel, stored,
                                subsurface_halo, write_frame)
from scanrig.sim.laser import raster_poses, trace_laser
from scanrig.sim.laser_exposure import nominal_peak_e_per_W
from scanrig.sim.render import CameraView
from scanrig.sim.scan_setup import scene_rig
from scanrig.sim.scene_file import load_scene_file
from scanrig.sim.sensor import Sensor
from scanrig.sim.session_writer import simulate_session
from tests.sim.test_scene_file import GOOD

#: Measured noise variance within 5 % of the model (relative standard error of a variance from
#: N >= 60 000 samples is sqrt(2 / N) < 0.6 %), as in test_noise.
NOISE_REL_TOL = 0.05
#: A JPEG round trip of a flat colour: 8-bit RGB -> YCbCr -> RGB rounds twice, at most 1 DN each.
JPEG_FLAT_TOL_DN = 2
#: Luma at quality 90 across a clipped stripe: the quality-90 luma quantiser steps of the
#: lowest frequencies are 2-4 DN, so block errors stay within a few of them.
JPEG_LUMA_TOL_DN = 8.0
LUMA_WEIGHTS = np.array([0.299, 0.587, 0.114])

#: 16-bit, 1 e-/DN, no black level: the noise-free output is the electron count itself.
LINEAR = Sensor(bit_depth=16, gain_e_per_dn=1.0, full_well_e=60000.0, black_level_dn=0.0)


def _stripe(shape=(64, 96), peak_e=8 * 10000.0, sigma_px=2.0, centre_px=48.3) -> np.ndarray:
    x = np.arange(shape[1]) - centre_px
    return np.tile(peak_e * np.exp(-0.5 * (x / sigma_px) ** 2), (shape[0], 1))


def test_crosstalk_ratios_on_an_unclipped_pixel():
    laser = np.zeros((5, 5))
    laser[2, 2] = 10000.0
    scene = np.full((5, 5), 500.0)
    rgb = colour_frame(scene, laser, LINEAR, ColourResponse(), None)
    assert rgb.dtype == np.uint16 and rgb.shape == (5, 5, 3)
    # 500 * ambient (1, 1, 0.92) + 10000 * laser (1, 0.06, 0.04)
    assert rgb[2, 2].tolist() == [10500, 1100, 860]
    assert rgb[0, 0].tolist() == [500, 500, 460]


def test_overexposed_stripe_clips_red_wide_and_green_blue_only_at_centre():
    sensor = Sensor()                                    # 8-bit, full well at 255 DN
    laser = _stripe(peak_e=8 * sensor.full_well_e)
    rgb = colour_frame(np.full(laser.shape, 3500.0), laser, sensor, ColourResponse(), None)
    row = rgb[32].astype(int)
    clipped = np.flatnonzero(row[:, 0] == sensor.max_dn)
    # R rounds to full scale from (max_dn - 0.5 - black level) * gain = 9902 e-: 3500 + 8e4 exp(-x²/8)
    # reaches it for |x| <= 4.49 px around 48.3, i.e. columns 44 to 52, nine pixels (G, B: one peak)
    assert clipped.tolist() == list(range(44, 53))
    # G: 0.06 * 8 * full well + 3500 e- at the peak, no clipping, maximum at the beam's centre
    assert np.argmax(row[:, 1]) == 48 and row[:, 1].max() < sensor.max_dn
    assert row[48, 1] == round((3500 + 0.06 * laser[32, 48]) / sensor.gain_e_per_dn + sensor.black_level_dn)


def test_clipping_at_sensor_max_in_every_channel():
    sensor = Sensor()
    laser = np.full((4, 4), 30 * sensor.full_well_e)
    rgb = colour_frame(np.zeros((4, 4)), laser, sensor, ColourResponse(), None)
    assert (rgb == sensor.max_dn).all()


def test_white_balance_below_one_clips_its_channel_below_full_scale():
    """A gain applied after the sensor clipped: red at 0.92 clips at round(0.92 * 255) = 235 DN,
    wherever the sensor clipped it, and every other pixel of red is scaled and rounded."""
    sensor = Sensor()
    laser = _stripe(peak_e=8 * sensor.full_well_e)
    scene = np.full(laser.shape, 3500.0)
    plain = colour_frame(scene, laser, sensor, ColourResponse(), None)
    balanced = colour_frame(scene, laser, sensor, ColourResponse(white_balance=(0.92, 1.0, 1.5)), None)
    assert balanced[..., 0].max() == 235
    assert np.array_equal(balanced[..., 0] == 235, plain[..., 0] == sensor.max_dn)
    assert np.array_equal(balanced[..., 0], np.rint(plain[..., 0] * np.float32(0.92)).astype(np.uint8))
    assert np.array_equal(balanced[..., 1], plain[..., 1])
    assert np.array_equal(balanced[..., 2], np.minimum(np.rint(plain[..., 2] * 1.5), 255).astype(np.uint8))


def test_halo_kernel_is_normalised_and_exponential():
    k = halo_kernel(3.0).astype(np.float64)
    h = k.shape[0] // 2
    assert k.shape == (2 * h + 1, 2 * h + 1) and h == 24
    assert k.sum() == pytest.approx(1.0, abs=1e-6)
    assert k[h, h + 3] / k[h, h] == pytest.approx(np.exp(-1.0), rel=1e-6)
    assert np.array_equal(k, k.T) and np.array_equal(k, k[::-1])


def test_halo_conserves_energy_and_keeps_the_direct_fraction():
    laser = np.zeros((81, 81))
    laser[40, 40] = 1000.0
    response = ColourResponse(halo_fraction=0.3, halo_radius_px=2.0)
    out = subsurface_halo(laser, response).astype(np.float64)
    k = halo_kernel(2.0)
    assert out.sum() == pytest.approx(1000.0, rel=1e-5)
    assert out[40, 40] == pytest.approx(1000.0 * (0.7 + 0.3 * k[16, 16]), rel=1e-5)
    assert out[40, 44] == pytest.approx(300.0 * k[16, 20], rel=1e-5)
    assert np.array_equal(subsurface_halo(laser, ColourResponse()), laser.astype(np.float32))


def test_halo_reaches_the_output_in_the_laser_channel():
    laser = np.zeros((41, 41))
    laser[20, 20] = 20000.0
    rgb = colour_frame(np.zeros_like(laser), laser, LINEAR, ColourResponse(halo_fraction=0.5, halo_radius_px=2.0),
                       None).astype(np.float64)
    expect_r = 10000.0 * halo_kernel(2.0)[16, 19]        # 3 px from the beam
    assert abs(rgb[20, 23, 0] - expect_r) <= 0.5
    assert abs(rgb[20, 23, 1] - 0.06 * expect_r) <= 0.5


def test_jpeg_differs_from_lossless_by_a_bounded_amount():
    sensor = Sensor()
    laser = _stripe(peak_e=8 * sensor.full_well_e)
    scene = np.full(laser.shape, 3500.0)
    lossless = colour_frame(scene, laser, sensor, ColourResponse(), None).astype(np.float64)
    jpeg = colour_frame(scene, laser, sensor, ColourResponse(jpeg_quality=90), None).astype(np.float64)
    assert jpeg.shape == lossless.shape
    diff = jpeg - lossless
    assert np.abs(diff[:, :32]).max() <= JPEG_FLAT_TOL_DN and np.abs(diff[:, -32:]).max() <= JPEG_FLAT_TOL_DN
    assert np.abs(diff @ LUMA_WEIGHTS).max() <= JPEG_LUMA_TOL_DN
    # 4:2:0 smears the colour difference R - G across the stripe's edges: the red edge moves
    assert np.abs(diff[..., 0]).max() > JPEG_LUMA_TOL_DN


def test_bayer_demosaic_of_a_flat_field_is_flat():
    sensor = Sensor()
    rgb = colour_frame(np.full((32, 48), 2000.0), np.full((32, 48), 1000.0), sensor,
                       ColourResponse(bayer=True), None)
    expect = colour_frame(np.full((1, 1), 2000.0), np.full((1, 1), 1000.0), sensor, ColourResponse(), None)[0, 0]
    assert (rgb == expect).all()


def test_bayer_keeps_rgb_order():
    rgb = colour_frame(np.zeros((8, 8)), np.full((8, 8), 5000.0), Sensor(), ColourResponse(bayer=True), None)
    assert rgb[4, 4, 0] > rgb[4, 4, 1] > rgb[4, 4, 2]


def test_seeded_noise_variance_matches_the_sensor_model_per_channel(rng):
    sensor = Sensor(bit_depth=12, gain_e_per_dn=10000.0 / 4095, read_noise_e=10.0)
    response = ColourResponse(laser_rgb=(1.0, 0.15, 0.05), ambient_rgb=(1.0, 0.8, 0.5))
    scene, laser = np.full((96, 96), 2000.0), np.full((96, 96), 4000.0)
    frames = np.stack([colour_frame(scene, laser, sensor, response, rng) for _ in range(8)]).astype(np.float64)
    measured = frames.var(axis=0, ddof=1).mean(axis=(0, 1))
    signal_e = 2000.0 * np.array(response.ambient_rgb) + 4000.0 * np.array(response.laser_rgb)
    model = sensor.noise_var_dn2(signal_e)
    assert np.all(np.abs(measured / model - 1) < NOISE_REL_TOL), (measured, model)
    mean_dn = signal_e / sensor.gain_e_per_dn + sensor.black_level_dn
    assert np.all(np.abs(frames.mean(axis=(0, 1, 2)) - mean_dn) < 0.05 * np.sqrt(model))


def test_same_seed_same_frame():
    scene, laser = np.full((16, 16), 2000.0), _stripe((16, 16), centre_px=8.0)
    a = colour_frame(scene, laser, Sensor(), ColourResponse(bayer=True), np.random.default_rng(5))
    b = colour_frame(scene, laser, Sensor(), ColourResponse(bayer=True), np.random.default_rng(5))
    assert np.array_equal(a, b)


@pytest.mark.parametrize("field, value, message", [
    ("laser_rgb", (1.0, 0.1), "colour laser_rgb must be 3 finite numbers >= 0, not all 0, got (1.0, 0.1)"),
    ("laser_rgb", (1.0, -0.1, 0.0), "colour laser_rgb must be 3 finite numbers >= 0, not all 0, got (1.0, -0.1, 0.0)"),
    ("ambient_rgb", (0, 0, 0), "colour ambient_rgb must be 3 finite numbers >= 0, not all 0, got (0, 0, 0)"),
    ("ambient_rgb", "white", "colour ambient_rgb must be 3 finite numbers >= 0, not all 0, got 'white'"),
    ("halo_fraction", 1.5, "colour halo_fraction must be in [0, 1], got 1.5"),
    ("halo_radius_px", 0.0, "colour halo_radius_px must be a positive number of pixels, got 0.0"),
    ("bayer", 1, "colour bayer must be true or false, got 1"),
    ("jpeg_quality", 0, "colour jpeg_quality must be an integer in [1, 100] or absent, got 0"),
    ("jpeg_quality", 90.0, "colour jpeg_quality must be an integer in [1, 100] or absent, got 90.0"),
    ("white_balance", (1.0, 0.0, 1.0), "colour white_balance must be 3 finite gains > 0, got (1.0, 0.0, 1.0)"),
    ("white_balance", (1.0, 1.0), "colour white_balance must be 3 finite gains > 0, got (1.0, 1.0)"),
])
def test_bad_response_fields(field, value, message):
    with pytest.raises(InputError) as err:
        ColourResponse(**{field: value})
    assert str(err.value) == message


def test_jpeg_needs_an_8_bit_sensor():
    with pytest.raises(InputError) as err:
        colour_frame(np.zeros((4, 4)), np.zeros((4, 4)), Sensor(bit_depth=12, gain_e_per_dn=2.5),
                     ColourResponse(jpeg_quality=90), None)
    assert str(err.value) == "colour jpeg_quality needs an 8-bit sensor, got bit_depth 12"


def test_scene_and_laser_shapes_must_match():
    with pytest.raises(ShapeError) as err:
        colour_frame(np.zeros((4, 4)), np.zeros((4, 5)), Sensor(), ColourResponse(), None)
    assert str(err.value) == "colour_frame: scene_e and laser_e must be (H, W) of the same shape, got (4, 4) and (4, 5)"


# --- scene files ------------------------------------------------------------------------------------
SCENE = GOOD  # a valid one-ball scene of the scene-file tests


def _scene_file(tmp_path, extra: str):
    path = tmp_path / "scene.toml"
    path.write_text(SCENE + extra)
    return path


def test_colour_stripe_scene_loads_a_colour_camera_and_overexposed_laser():
    scene = load_scene("colour_stripe")
    assert scene.colour == ColourResponse(laser_rgb=(1.0, 0.07, 0.08), ambient_rgb=(1.0, 1.0, 0.92),
                                          halo_fraction=0.3, halo_radius_px=3.0, bayer=True, jpeg_quality=90)
    peak_e = scene.laser.stripe_power_W * nominal_peak_e_per_W(scene.laser, scene.sensor, scene.rig,
                                                                 scene.center_m, "stripe")
    assert peak_e == pytest.approx(16.0 * scene.sensor.full_well_e, rel=1e-12)


def test_grey_scenes_have_no_colour(tmp_path):
    assert load_scene("default").colour is None
    assert load_scene_file(_scene_file(tmp_path, "\n[camera]\ncolor = false\n")).colour is None


def test_camera_table_sets_the_response_and_only_overexposure_for_grey(tmp_path):
    scene = load_scene_file(_scene_file(tmp_path, "\n[camera]\ncolor = true\nlaser_rgb = [1.0, 0.1, 0.1]\n"
                                                  "white_balance = [0.92, 1.0, 1.1]\n"))
    assert scene.colour == ColourResponse(laser_rgb=(1.0, 0.1, 0.1), white_balance=(0.92, 1.0, 1.1))
    grey = load_scene_file(_scene_file(tmp_path, "\n[camera]\nlaser_overexposure = 2.0\n"))
    assert grey.colour is None
    assert grey.laser.power_W * nominal_peak_e_per_W(grey.laser, grey.sensor, grey.rig, grey.center_m, "spot") \
        == pytest.approx(2.0 * grey.sensor.full_well_e, rel=1e-12)


@pytest.mark.parametrize("extra, message", [
    ("\n[camera]\ncolour = true\n", "[camera]: unknown field 'colour' (did you mean 'color'?)"),
    ("\n[camera]\ncolor = 1\n", "[camera]: color must be true or false, got 1"),
    ("\n[camera]\nhalo_fraction = 0.2\n", "[camera]: halo_fraction applies to colour cameras; set color = true"),
    ("\n[camera]\ncolor = true\nhalo_fraction = 2.0\n", "[camera]: colour halo_fraction must be in [0, 1], got 2.0"),
    ("\n[camera]\ncolor = true\njpeg_quality = 90\n[sensor]\nbit_depth = 12\ngain_e_per_dn = 2.5\n",
     "[camera]: colour jpeg_quality needs an 8-bit sensor, got bit_depth 12"),
    ("\n[camera]\nlaser_overexposure = 0\n", "[camera]: laser_overexposure must be a positive number, got 0"),
    ("\n[camera]\nlaser_overexposure = 5.0\n[laser]\nstripe_power_W = 0.1\n",
     "[camera]: laser_overexposure sets the laser's powers; remove stripe_power_W from [laser]"),
    ("\n[camera]\n[camera.x]\n", "[camera]: unknown field 'x'"),
])
def test_bad_camera_table(tmp_path, extra, message):
    path = _scene_file(tmp_path, extra)
    with pytest.raises(FileFormatError) as err:
        load_scene_file(path)
    assert str(err.value).startswith(f"{path}: {message}")


def test_scene_refuses_jpeg_from_a_16_bit_sensor():
    with pytest.raises(InputError) as err:
        replace(load_scene("colour_stripe"), sensor=Sensor(bit_depth=16, gain_e_per_dn=0.2))
    assert str(err.value) == "colour jpeg_quality needs an 8-bit sensor, got bit_depth 16"


# --- rendering and sessions ------------------------------------------------------------------------
#: Rows whose direct laser peak exceeds this multiple of the full well are checked in sessions:
#: G's rise there (~7 % of the peak) clearly exceeds the printed texture's contrast, which on
#: weaker rows can put G's maximum on bright paper beside the stripe.
STRONG_ROW_FULL_WELLS = 5.0
#: Noise and 4:2:0 JPEG (R - G smeared over 2 px) move G's maximum or R's clip at the centre on
#: a few of those rows (measured 0 to 2 % at seed 1).
SESSION_ROW_FRACTION = 0.95


def _colour_view(scale: float = 0.25):
    scene = load_scene("colour_stripe")
    rig = scene_rig(scene, 1, scale)
    poses = raster_poses(scene.laser, scene.center_m, scene.radius_m, 3, "stripe")
    return scene, rig, CameraView(rig.cameras[0], scene), poses


def test_laser_window_grown_by_the_halo_matches_the_full_frame():
    scene, _, view, poses = _colour_view()
    window = view.laser_window(trace_laser(poses[1], scene.laser, scene))
    grown = window.padded(scene.colour.halo_pad_px, view.background_e.shape)
    laser = np.zeros_like(view.background_e)
    laser[window.slices] = window.electrons
    full = channel_electrons(view.background_e, laser, scene.colour)
    inside = channel_electrons(view.background_e[grown.slices], grown.electrons, scene.colour)
    assert np.allclose(full[grown.slices], inside, rtol=1e-5, atol=1e-3)
    outside = full.copy()
    outside[grown.slices] = 0.0
    scene_only = view.background_e[..., None] * np.float32(scene.colour.ambient_rgb)
    scene_only[grown.slices] = 0.0
    assert np.allclose(outside, scene_only, rtol=1e-5, atol=1e-3)


def test_jpeg_file_reads_back_as_the_stored_image(tmp_path):
    rgb = colour_frame(np.full((32, 48), 4000.0), _stripe((32, 48), centre_px=20.0), Sensor(),
                       ColourResponse(bayer=True), np.random.default_rng(3))
    response = ColourResponse(bayer=True, jpeg_quality=90)
    path = write_frame(tmp_path / "frame", rgb, response)
    assert path.name == "frame.jpg"
    assert np.array_equal(read_image(path), stored(rgb, response))
    assert write_frame(tmp_path / "frame", rgb, ColourResponse()).name == "frame.png"
    assert np.array_equal(read_image(tmp_path / "frame.png"), rgb)


@pytest.mark.slow
def test_colour_stripe_session_is_rgb_with_a_clipped_red_band_and_green_blue_peaks_at_the_centre(tmp_path):
    scene, rig, view, poses = _colour_view(0.5)
    out = simulate_session(tmp_path / "s", scene="colour_stripe", mode="stripe", n_frames=3,
                           rng=np.random.default_rng(1), n_shots=1, rig=rig, workers=1)
    assert tomllib.loads((out / "session.toml").read_text())["laser_color"] == "red"
    shape = (rig.cameras[0].height, rig.cameras[0].width, 3)
    for path in [out / "scan" / "cam0" / "dark.jpg", out / "calibration" / "cam0" / "000.jpg"]:
        assert read_image(path).shape == shape
    half = 8
    for i, pose in enumerate(poses):
        image = read_image(out / "scan" / "cam0" / f"{i:05d}.jpg")
        assert image.shape == shape and image.dtype == np.uint8
        image = image.astype(np.int64)
        window = view.laser_window(trace_laser(pose, scene.laser, scene))
        rows = np.flatnonzero(window.electrons.max(axis=1) > STRONG_ROW_FULL_WELLS * scene.sensor.full_well_e)
        centre = window.electrons.argmax(axis=1)[rows] + window.u0      # the truth: the beam's centre
        cols = centre[:, None] + np.arange(-half, half + 1)
        inside = (cols.min(axis=1) >= 0) & (cols.max(axis=1) < shape[1])
        assert inside.sum() > 100
        profile = image[(rows + window.v0)[inside, None], cols[inside]]  # (rows, 2 half + 1, RGB)
        r_clipped = profile[..., 0] >= scene.sensor.max_dn - 5
        assert np.mean(r_clipped[:, half]) >= SESSION_ROW_FRACTION
        offset = profile.argmax(axis=1) - half
        assert np.mean(np.abs(offset[:, 1]) <= 1) >= SESSION_ROW_FRACTION
        assert np.mean(np.abs(offset[:, 2]) <= 1) >= SESSION_ROW_FRACTION
        # R is clipped over a wider band than G's peak
        g_peak = profile[..., 1] >= profile[..., 1].max(axis=1, keepdims=True) - 5
        assert np.median(r_clipped.sum(axis=1)) > np.median(g_peak.sum(axis=1))


def test_fast_colour_frames_have_the_full_frame_mean_and_noise(rng):
    """Noisy frames of the fast path (per-channel noise fields, halo-grown laser window) against the
    full-frame model: per pixel, z = (mean of N frames - model mean) / model sd of that mean. A spot
    has a small window, so much of its halo falls in the ring the halo adds around it."""
    scene, _, view, _ = _colour_view()
    scene = replace(scene, colour=replace(scene.colour, bayer=False, jpeg_quality=None))
    view = CameraView(view.camera, scene, rng=rng)
    spot = raster_poses(scene.laser, scene.center_m, scene.radius_m, 9, "spot")[4]
    trace = trace_laser(spot, scene.laser, scene)
    window = view.laser_window(trace)
    laser = np.zeros_like(view.background_e)
    laser[window.slices] = window.electrons
    electrons = channel_electrons(view.background_e, laser, scene.colour).astype(np.float64)
    sensor, n_frames = scene.sensor, 12
    frames = np.stack([view.sensor_frame(trace, rng) for _ in range(n_frames)]).astype(np.float64)
    model_mean = electrons / sensor.gain_e_per_dn + sensor.black_level_dn
    model_sd = np.sqrt(sensor.noise_var_dn2(electrons) / n_frames)
    unclipped = model_mean + 5 * np.sqrt(sensor.noise_var_dn2(electrons)) < sensor.max_dn
    z = (frames.mean(axis=0) - model_mean) / model_sd
    ring = np.zeros(electrons.shape, dtype=bool)
    ring[window.padded(scene.colour.halo_pad_px, laser.shape).slices] = True
    ring[window.slices] = False
    for part in (unclipped, unclipped & ring):
        assert part.sum() > 1000
        # z of n independent pixels: mean within 5 / sqrt(n), variance within NOISE_REL_TOL of 1
        assert abs(z[part].mean()) < 5 / np.sqrt(part.sum())
        assert abs(z[part].var() - 1) < NOISE_REL_TOL
