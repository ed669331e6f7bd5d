"""Each camera's corners alone against the rig (:mod:`scanrig.calibration.camera_agreement`): quiet
when the cameras see the target at the same instant, a warning naming the camera when the target
moved between its exposure and the others'."""

from __future__ import annotations

import numpy as np
import pytest

from scanrig.calibration.camera_agreement import P_WARN, agreement_warnings, camera_agreement
from scanrig.calibration.observations import Observations
from scanrig.calibration.pipeline import calibrate
from scanrig.calibration.summary import format_summary
from scanrig.calibration.synthetic import DETECTABLE_SQUARE_PX, observe, ring_cameras, simulate
from scanrig.geometry.transform import RigidTransform
from scanrig.targets import cube

TARGET = cube()
SIGMA_PX = 0.1
N_SHOTS = 12
#: Where camera 1 sees the target: the others' pose moved by this much (m, Gaussian per axis and
#: shot), about 0.5 px at 0.8 m and f 1400 px, five times the corners' noise: a board moved by
#: hand while unsynchronised cameras expose.
MOTION_M = 3e-4
#: With agreeing cameras ``ratio²`` is F over ~40 and ~1000 degrees of freedom: sd about 0.11 in
#: the ratio, so 0.6-1.5 is about 4 sd.
RATIO_RANGE = (0.6, 1.5)


def _agreeing(seed: int) -> Observations:
    rng = np.random.default_rng(seed)
    return simulate(ring_cameras(3, rng=rng), TARGET, N_SHOTS, SIGMA_PX, rng, cover=True,
                    min_square_px=DETECTABLE_SQUARE_PX).obs


def _moved_for_camera_1(seed: int) -> Observations:
    """The session of :func:`_agreeing`, but camera 1 sees every shot's target moved by ~MOTION_M."""
    rng = np.random.default_rng(seed)
    cams = ring_cameras(3, rng=rng)
    sim = simulate(cams, TARGET, N_SHOTS, SIGMA_PX, rng, cover=True, min_square_px=DETECTABLE_SQUARE_PX)
    moved = [RigidTransform(p.R, p.t + rng.normal(scale=MOTION_M, size=3)) for p in sim.world_from_target]
    seen = observe([cams[1]], TARGET, moved, SIGMA_PX, rng, DETECTABLE_SQUARE_PX)
    keep = sim.obs.camera != 1
    return Observations(np.concatenate([sim.obs.camera[keep], np.ones(len(seen), dtype=np.int64)]),
                        np.concatenate([sim.obs.shot[keep], seen.shot]),
                        np.concatenate([sim.obs.point_id[keep], seen.point_id]),
                        np.concatenate([sim.obs.uv[keep], seen.uv]),
                        np.concatenate([sim.obs.weight[keep], seen.weight]),
                        sim.obs.camera_names, sim.obs.shot_names, sim.obs.image_sizes)


def _agreement(obs: Observations) -> dict:
    result = calibrate(obs, TARGET, "opencv5", cross_validate=False)
    return camera_agreement(result.bundle, result.uncertainty.covariance, TARGET, {})


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_agreeing_cameras_are_not_warned_about(seed):
    agreement = _agreement(_agreeing(seed))
    assert set(agreement) == {"cam0", "cam1", "cam2"}
    for a in agreement.values():
        assert RATIO_RANGE[0] < a.ratio < RATIO_RANGE[1]
        assert a.p_value > P_WARN
        assert a.rms_alone_px <= a.rms_rig_px   # the rig is a special case of the camera alone
        assert 20 < a.dof < 80                  # ~6 per shot the camera shares, less its pose
    assert agreement_warnings(agreement) == []


def test_a_camera_that_saw_the_target_elsewhere_is_warned_about():
    """Camera 1 is the one flagged most; the two others, whose shared poses it pulls, may be too."""
    agreement = _agreement(_moved_for_camera_1(0))
    assert agreement["cam1"].p_value < P_WARN
    assert agreement["cam1"].ratio == max(a.ratio for a in agreement.values())
    assert agreement["cam1"].ratio > 3.0
    lines = agreement_warnings(agreement)
    line = next(line for line in lines if line.startswith("cam1: "))
    assert f"its corners fit {agreement['cam1'].rms_alone_px:.2f} px alone but " in line
    assert line.endswith("the cameras disagree about where the target was, and the rig's sigmas are too small "
                         "(what to do: calibration_report/summary.txt)")


def test_calibrate_reports_the_cameras_apart_in_its_summary():
    result = calibrate(_moved_for_camera_1(0), TARGET, "opencv5")
    assert result.camera_agreement["cam1"].p_value < P_WARN
    assert any(w.startswith("cam1: its corners fit") for w in result.warnings)
    text = format_summary(result)
    assert "cameras apart cam1: RMS" in text
    assert "Likely causes:" in text.split("cameras apart cam2")[1]


def test_one_camera_has_nothing_to_disagree_with():
    rng = np.random.default_rng(3)
    obs = simulate(ring_cameras(1, rng=rng), TARGET, N_SHOTS, SIGMA_PX, rng, cover=True,
                   min_square_px=DETECTABLE_SQUARE_PX, min_cameras=1).obs
    result = calibrate(obs, TARGET, "opencv5")
    assert result.camera_agreement == {"cam0": None}
    assert agreement_warnings(result.camera_agreement) == []
    assert "cameras apart" not in format_summary(result)
