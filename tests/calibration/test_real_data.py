"""Calibration on real images and detections from tests/data."""

from __future__ import annotations

import csv
from pathlib import Path

import cv2
import numpy as np
import pytest

import scanrig
from scanrig.calibration.corners_csv import read_corners_csv
from scanrig.calibration.observations import Observations
from scanrig.calibration.pipeline import calibrate
from scanrig.cli.main import main
from scanrig.io.rig_file import load_rig_info
from scanrig.targets import charuco
from tests.data_paths import real_data

#: OpenCV's ``calibrateCamera`` RMS on the same corners may differ from ours by round-off of the
#: solvers' stopping points; ours must not exceed it by more than this (pixels).
RMS_SLACK_PX = 1e-3


def opencv_stereo_session(root: Path) -> Path:
    """calibration/left|right/NN.jpg (symlinks) + a 9x6 chessboard target.toml (square 0.025 unit)."""
    src = real_data("opencv-stereo-9x6")
    for side in ("left", "right"):
        (root / "calibration" / side).mkdir(parents=True)
        for img in sorted(src.glob(f"{side}*.jpg")):
            (root / "calibration" / side / img.name.removeprefix(side)).symlink_to(img)
    (root / "target.toml").write_text('kind = "chessboard"\ninner_corners = [9, 6]\nsquare_m = 0.025\n')
    return root


@pytest.fixture(scope="module")
def opencv_calibrated(tmp_path_factory):
    root = opencv_stereo_session(tmp_path_factory.mktemp("ocv"))
    assert main(["calibrate", str(root), "--no-plots"]) == 0
    return root


def test_opencv_stereo_all_boards_found_and_rms_not_above_opencv(opencv_calibrated):
    from scanrig.calibration.bundle import bundle_adjust
    from scanrig.calibration.init import initialise
    from scanrig.targets import load_target

    root = opencv_calibrated
    rig, info, _ = load_rig_info(root / "rig.toml")
    obs = read_corners_csv(root / "calibration_report" / "corners.csv", {"left": (640, 480), "right": (640, 480)})
    counts = obs.view_counts()
    assert counts.shape == (2, 13) and np.all(counts == 54)          # every board in all 26 images
    target = load_target(root / "target.toml")
    obj = target.boards[0].points_board.astype(np.float32)
    pts, mono_cv = [], []
    for c, name in enumerate(["left", "right"]):
        rows = obs.camera == c
        img_pts = [obs.uv[rows & (obs.shot == s)][np.argsort(obs.point_id[rows & (obs.shot == s)])].astype(np.float32)
                   for s in range(13)]
        pts.append(img_pts)
        rms_cv, K, dist, _, _ = cv2.calibrateCamera([obj] * 13, img_pts, (640, 480), None, None)
        mono_cv.append((K, dist))
        # Same corners, same model, same objective (plain least squares, one camera): our RMS
        # over every corner is not above OpenCV's.
        mono = obs.subset(rows)
        mono = Observations(np.zeros(len(mono), int), mono.shot, mono.point_id, mono.uv, mono.weight,
                            [name], mono.shot_names, {name: (640, 480)})
        init = initialise(mono, target, {name: "opencv5"})
        res = bundle_adjust(mono, target, init.cameras, init.world_from_target, init.reference_shot, robust=False)
        print(f"{name}: RMS ours {res.rms_px():.5f} px, OpenCV calibrateCamera {rms_cv:.5f} px; "
              f"joint robust solve {info[name]['rms_px']:.5f} px")
        assert res.rms_px() <= rms_cv + RMS_SLACK_PX
    # The joint solve against OpenCV's joint solve (stereoCalibrate, intrinsics free) on the same
    # corners: intrinsics within 3 of our reported sigmas.
    out = cv2.stereoCalibrate([obj] * 13, pts[0], pts[1], *mono_cv[0], *mono_cv[1], (640, 480),
                              flags=cv2.CALIB_USE_INTRINSIC_GUESS,
                              criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12))
    for name, K in (("left", out[1]), ("right", out[3])):
        std = np.array(info[name]["params_std"])
        theirs = np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2]])
        print(f"{name}: fx fy cx cy ours {rig[name].params[:4].round(3)} ± {std[:4].round(3)}, "
              f"OpenCV stereo {theirs.round(3)}")
        assert np.all(np.abs(rig[name].params[:4] - theirs) <= 3 * std[:4])
    baseline_cv = float(np.linalg.norm(out[6]))
    baseline = float(np.linalg.norm(rig["left"].center_world - rig["right"].center_world))
    print(f"baseline ours {baseline:.5f}, OpenCV stereoCalibrate {baseline_cv:.5f} (units of square 0.025)")


def test_opencv_stereo_baseline_and_board_size(opencv_calibrated):
    rig = scanrig.load_rig(opencv_calibrated / "rig.toml")
    baseline = np.linalg.norm(rig["left"].center_world - rig["right"].center_world)
    # OpenCV 5 stereo result (PROVENANCE.md): 0.0836 units = 3.34 squares; 1 % tolerance there.
    assert baseline == pytest.approx(0.0836, rel=0.01)
    obs = read_corners_csv(opencv_calibrated / "calibration_report" / "corners.csv",
                           {"left": (640, 480), "right": (640, 480)})
    q = np.full((2, 13 * 54, 2), np.nan)
    idx = obs.shot * 54 + obs.point_id
    q[obs.camera, idx] = obs.uv
    p, _ = scanrig.triangulate(rig, q)
    grid = p.reshape(13, 6, 9, 3)
    spacing = np.concatenate([np.linalg.norm(np.diff(grid, axis=2), axis=3).ravel(),
                              np.linalg.norm(np.diff(grid, axis=1), axis=3).ravel()])
    # OpenCV's own stereo result gives mean 0.025033, std 0.00039 (PROVENANCE.md).
    assert np.nanmean(spacing) == pytest.approx(0.025, abs=0.0001)
    assert np.nanstd(spacing) < 0.0005


def _caliscope_observations() -> Observations:
    path = real_data("caliscope-4cam-charuco") / "post_optimization" / "CHARUCO" / "xy_CHARUCO.csv"
    rows = list(csv.DictReader(open(path, newline="")))
    shots = sorted({int(r["sync_index"]) for r in rows})
    names = [f"cam_{i}" for i in range(4)]
    return Observations(
        np.array([int(r["cam_id"]) for r in rows]), np.searchsorted(shots, [int(r["sync_index"]) for r in rows]),
        np.array([int(r["keypoint_id"]) for r in rows]),
        np.array([[float(r["img_loc_x"]), float(r["img_loc_y"])] for r in rows]), np.ones(len(rows)),
        names, [str(s) for s in shots], {n: (1280, 720) for n in names})


def test_caliscope_four_cameras_jointly():
    obs = _caliscope_observations()
    target = charuco((4, 5), 0.054, 0.0405, "DICT_4X4_1000")
    result = calibrate(obs, target, "opencv4", cross_validate=False)
    assert result.rig.names == ["cam_0", "cam_1", "cam_2", "cam_3"]
    # caliscope's own result reprojects at 1.66 px RMS (PROVENANCE.md); ours over ALL detections:
    all_rms = float(np.sqrt(np.nanmean(np.sum(result.bundle.residuals_px ** 2, axis=1))))
    assert result.bundle.rms_px() < 1.66
    print(f"caliscope: RMS inliers {result.bundle.rms_px():.3f} px, all {all_rms:.3f} px, "
          f"{len(result.bundle.outliers)} outliers of {len(obs)}")
    # Triangulate every corner seen by >= 2 cameras; neighbours in a row/column are 54 mm apart.
    n_ids = 12
    q = np.full((4, len(obs.shot_names) * n_ids, 2), np.nan)
    q[obs.camera, obs.shot * n_ids + obs.point_id] = obs.uv
    p, _ = scanrig.triangulate(result.rig, q)
    grid = p.reshape(len(obs.shot_names), 4, 3, 3)
    d = np.concatenate([np.linalg.norm(np.diff(grid, axis=2), axis=3).ravel(),
                        np.linalg.norm(np.diff(grid, axis=1), axis=3).ravel()])
    d = d[np.isfinite(d)]
    print(f"caliscope neighbour distance {1000 * d.mean():.2f} ± {1000 * d.std():.2f} mm over {len(d)} pairs")
    assert abs(d.mean() - 0.054) < 0.001


#: Stereo baseline of the MRPT pairs from OpenCV's own stereo calibration, in squares
#: (tests/data/mrpt-stereo-9x6/PROVENANCE.md); the corner noise of 0.2 px over 4 views
#: leaves about 0.1 % on it.
MRPT_BASELINE_SQUARES = 3.515


def test_mrpt_four_pairs_converge_and_flag_what_they_cannot_determine(tmp_path):
    """Only 4 views: the solve must converge and say which parameters stay uncertain."""
    from scanrig.calibration.pipeline import detect_session
    from scanrig.io.session import Session
    from scanrig.targets import load_target

    src = real_data("mrpt-stereo-9x6")
    for side in ("left", "right"):
        (tmp_path / "calibration" / side).mkdir(parents=True)
        for img in sorted(src.glob(f"*_{side}.jpg")):
            (tmp_path / "calibration" / side / img.name.replace(f"_{side}", "")).symlink_to(img)
    (tmp_path / "target.toml").write_text('kind = "chessboard"\ninner_corners = [9, 6]\nsquare_m = 1.0\n')
    target = load_target(tmp_path / "target.toml")
    obs, not_found = detect_session(Session(tmp_path), target)
    assert len(not_found) == 0                       # the board is found in all 8 images
    result = calibrate(obs, target, "opencv5", cross_validate=False)
    assert result.bundle.rms_px() < 0.3
    rig = result.rig
    baseline = np.linalg.norm(rig["left"].center_world - rig["right"].center_world)
    assert baseline == pytest.approx(MRPT_BASELINE_SQUARES, rel=2e-3)
    for name in ("left", "right"):                 # the 6th-order term is what 4 views leave open
        assert "k3" in [p for p, _, _ in result.uncertainty.poorly_determined[name]]
        assert sum(w.startswith(f"{name}: distortion not determined") and "k3 ±" in w for w in result.warnings) == 1
