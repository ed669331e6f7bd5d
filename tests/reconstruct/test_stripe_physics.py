"""Stripe mode against ground truth: reflections, edge-on sheets, straight stripes, calibration error.

The traces are made by projecting known 3-D curves (``synth.curve_traces``) with Gaussian noise
of ``SIGMA_PX`` on the measured coordinate; nothing of the reconstruction is used to make them.
"""

import numpy as np
import pyarrow as pa
import pytest

from scanrig.geometry import Rig
from scanrig.reconstruct.candidates import frame_order
from scanrig.reconstruct.stripes import reconstruct_stripes
from scanrig.reconstruct.stripes.accept import greedy_unique
from scanrig.reconstruct.stripes.floor import estimate_calibration_floor, floor_samples
from scanrig.reconstruct.stripes.views import frame_views
from tests.reconstruct.synth import curve_traces, height_field, plane_curve, ring_rig

#: Detection noise across the stripe (px), as in test_stripes.
SIGMA_PX = 0.2
#: With 0.2 px noise (plus the 0.1 px calibration floor) the points' sigma is ~0.1-0.2 mm; the
#: issue's acceptance figure, 0.1 mm RMS, is about one sigma.
RMS_TOL_M = 1e-4
#: A gross error: several times the sigma of any point of these rigs.
OUTLIER_M = 1e-3
#: A point farther from its frame's light plane than this many of its own sigmas is not a stripe
#: point (sigma is the largest axis of its covariance, so its distance along one direction exceeds
#: 5 sigma with probability < 1e-5).
PLANE_SIGMAS = 5.0
#: The reflection is brighter than the stripe (a shiny surface): rank 0 on its scan lines.
STRIPE_PEAK, REFLECTION_PEAK = 150.0, 300.0


@pytest.fixture(scope="module")
def rig():
    return ring_rig(height_m=0.6)


def _heights(cloud):
    p = cloud.p_world
    return p[:, 2] - height_field(p[:, 0], p[:, 1])


def test_secondary_reflection_seen_by_every_camera_is_rejected(rig):
    """A reflection is a real lit curve on the surface: all cameras see it, consistently in 3-D.

    Three-view agreement cannot reject it (it passes its χ²); only the light plane can. It is
    brighter than the stripe, so "brightest candidate per scan line" would pick it.
    """
    offsets = [-0.06, 0.05]
    curves = []
    tilt = np.radians(30.0)
    for k, s in enumerate(offsets):
        curves.append((f"s{k:03d}", plane_curve([1.0, 0.0, 0.0], s), STRIPE_PEAK))
        # 11-69 mm beside the stripe, across it at 30°, on the same surface
        normal = np.array([np.cos(tilt), np.sin(tilt), 0.0])
        curves.append((f"s{k:03d}", plane_curve(normal, normal @ [s + 0.04, 0.0, 0.0], t_range=(-0.05, 0.05)),
                       REFLECTION_PEAK))
    table = curve_traces(rig, curves, np.random.default_rng(71), SIGMA_PX)
    peak, rank = table.column("peak").to_numpy(), table.column("rank").to_numpy()
    brightest_reflection = (peak == REFLECTION_PEAK) & (rank == 0)
    cameras = np.array(table.column("camera").to_pylist())
    assert set(cameras[brightest_reflection]) == set(rig.names)

    cloud, summary = reconstruct_stripes(rig, table, frame_order(table), np.random.default_rng(0))
    plane_x = np.array(offsets)[cloud.frame]
    off_plane = np.abs(cloud.p_world[:, 0] - plane_x)
    assert np.all(off_plane <= PLANE_SIGMAS * cloud.sigma)  # no reflection point survives
    dz = _heights(cloud)
    assert np.all(np.abs(dz) < OUTLIER_M)
    assert np.sqrt(np.mean(dz**2)) < RMS_TOL_M
    assert summary["pairs_off_plane"] > 0
    # the stripe is kept where the reflection competes with it (|y| < 43 mm, ~100 rows a frame)
    beside = np.abs(cloud.p_world[:, 1]) < 0.043
    assert np.all(np.bincount(cloud.frame[beside], minlength=2) >= 100)


def test_edge_on_light_sheet_gets_an_honest_sigma(rig):
    """Two cameras in the light plane: their stripes are their epipolar lines, no depth at all.

    Only the third camera, 4° off the sheet, measures depth, so the points are imprecise — but
    their sigma must say so (interpolated crossings used to claim ~0.1 mm for mm errors).
    """
    c0, c2 = rig.cameras[0].center_world, rig.cameras[2].center_world
    curves = []
    for k, y0 in enumerate([-0.04, 0.03]):
        through = np.array([0.0, y0, 0.0])
        normal = np.cross(c2 - c0, through - c0)
        normal /= np.linalg.norm(normal)
        curves.append((f"s{k:03d}", plane_curve(normal, normal @ through), STRIPE_PEAK))
    table = curve_traces(rig, curves, np.random.default_rng(72), SIGMA_PX)
    cloud, _ = reconstruct_stripes(rig, table, frame_order(table), np.random.default_rng(0), max_sigma_m=np.inf)
    assert len(cloud) > 200
    whitened = _heights(cloud) / cloud.sigma
    # one component against the largest axis: RMS at most 1 when sigma is honest
    assert np.sqrt(np.mean(whitened**2)) <= 1.0
    assert np.all(np.abs(whitened) <= PLANE_SIGMAS)


def test_two_view_points_are_not_tested_by_a_plane_that_a_straight_stripe_leaves_loose(rig):
    """A stripe that three cameras see only on the flat floor fixes a line, not a plane.

    A raised piece of the same stripe (a box top 40 mm up) is hidden from the third camera, so
    every point of the frame off the floor line is a two-view point whose only test is the
    plane; and the epipolar lines of the floor cross the box top in the other camera, making
    wrong matches far off the light plane with a sigma of a few tenths of a millimetre. The
    plane's tilt about the floor line is free: its position there is unknown, its χ² passes
    them all (the sphere session's frame 24: points 0.1 m below the floor). They must be
    rejected by the tests, not by the precision cut.
    """
    azimuth, box_m = np.radians(60.0), 0.04
    normal = np.array([np.cos(azimuth), np.sin(azimuth), 0.0])  # vertical light plane through 0
    along = np.cross(normal, [0.0, 0.0, 1.0])
    t = np.linspace(-0.15, 0.15, 3000)
    floor = t[(t < -0.03) | (t > 0.06), None] * along
    top = t[(t >= 0.0) & (t <= 0.06), None] * along + [0.0, 0.0, box_m]
    cams = list(rig.cameras)
    table = pa.concat_tables([curve_traces(rig, [("s000", floor, STRIPE_PEAK)], np.random.default_rng(75), SIGMA_PX),
                              curve_traces(Rig(cams[:2]), [("s000", top, STRIPE_PEAK)], np.random.default_rng(76),
                                           SIGMA_PX)])
    cloud, _ = reconstruct_stripes(rig, table, frame_order(table), np.random.default_rng(0), max_sigma_m=np.inf)
    assert (cloud.n_views >= 3).sum() > 200  # the floor line is kept
    assert np.all(np.abs(cloud.p_world @ normal) <= PLANE_SIGMAS * cloud.sigma)
    z = cloud.p_world[:, 2]
    assert np.all(np.minimum(np.abs(z), np.abs(z - box_m)) < OUTLIER_M)


def test_calibration_floor_is_raised_only_where_the_calibration_is_wrong(rig):
    """A camera whose distortion is wrong towards its borders: the three-view points show it."""
    curves = [(f"s{k:03d}", plane_curve([1.0, 0.0, 0.0], s), STRIPE_PEAK)
              for k, s in enumerate(np.linspace(-0.13, 0.13, 9))]
    table = curve_traces(rig, curves, np.random.default_rng(73), SIGMA_PX)
    cams = list(rig.cameras)
    params = cams[2].params.copy()
    params[5] += 6.0  # k2: 1.9 px at the 400 px radius the stripes reach, 0.06 px at 200 px
    wrong = Rig([cams[0], cams[1], cams[2].with_params(params)])

    def floor(r):
        frames = np.array(table.column("frame").to_pylist())
        views = [frame_views(r, table.filter(pa.array(frames == f)), np.eye(2) * 0.01)
                 for f in sorted(set(frames))]
        samples = [x for v in views for x in floor_samples(r, v)]
        return estimate_calibration_floor(samples, len(r))

    edges, s2_true = floor(rig)
    assert np.sqrt(s2_true.max()) < 0.5 * SIGMA_PX  # nothing beyond the detection noise
    edges, s2_wrong = floor(wrong)
    sigma_extra = np.sqrt(s2_wrong)
    assert sigma_extra[2].max() > SIGMA_PX  # the wrong camera, beyond its detection noise
    assert sigma_extra[2][edges < 200].max() < 0.5 * SIGMA_PX  # but not near its centre
    cloud, summary = reconstruct_stripes(wrong, table, frame_order(table), np.random.default_rng(0))
    assert summary["floor_extra_px"] == pytest.approx(sigma_extra.max(), abs=1e-3)
    dz = _heights(cloud)
    assert np.all(np.abs(dz) < OUTLIER_M)
    assert np.sqrt(np.mean(dz**2)) < RMS_TOL_M


def test_each_detection_supports_at_most_one_point():
    """The vectorised greedy selection equals the sequential one and never reuses a detection."""
    rng = np.random.default_rng(74)
    det_ids = rng.integers(-1, 40, size=(300, 3))
    priority = rng.permutation(300)
    accepted = greedy_unique(det_ids, priority)
    taken, expected = set(), np.zeros(300, bool)
    for row in np.argsort(priority):
        ids = {int(d) for d in det_ids[row] if d >= 0}
        if not ids & taken:
            expected[row] = True
            taken |= ids
    assert np.array_equal(accepted, expected)
    used = det_ids[accepted][det_ids[accepted] >= 0]
    assert len(used) == len(np.unique(used))
