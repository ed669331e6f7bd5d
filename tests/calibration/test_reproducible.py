"""The same detections give bit-identical calibrations, in one process and across processes."""

from __future__ import annotations

import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest

from scanrig.calibration.corners_csv import write_corners_csv
from scanrig.calibration.init import _spanning_tree
from scanrig.calibration.pipeline import REPORT_DIR, calibrate
from scanrig.calibration.summary import format_summary
from scanrig.calibration.synthetic import ring_cameras, simulate
from scanrig.geometry.transform import RigidTransform
from scanrig.io.rig_file import rig_to_toml
from scanrig.io.session import write_image
from scanrig.targets import cube, save_target

#: Injected detection noise, pixels.
SIGMA_PX = 0.1
#: Shots of the cube: 3 per half, so the cross-validation runs as well.
N_SHOTS = 6
#: Starts of the rig.toml lines that record when it was written.
DATE_LINES = ("date = ", "# written by")


@pytest.fixture(scope="module")
def cube_views():
    """Three cameras x six cube shots: whole faces in view, so many views have equal point counts."""
    rng = np.random.default_rng(3)
    target = cube()
    sim = simulate(ring_cameras(3, rng=rng), target, N_SHOTS, SIGMA_PX, rng, max_shift_m=0.15)
    counts = sim.obs.view_counts()
    assert len(np.unique(counts[counts > 0])) < np.count_nonzero(counts)   # ties to break
    return sim.obs, target


def _outputs(result) -> dict:
    """Everything a calibration writes or hands on, as exact values."""
    b, unc = result.bundle, result.uncertainty
    return {"rig.toml": rig_to_toml(result.rig, result.camera_info()),
            "summary.txt": format_summary(result),
            "x": b.x, "residuals_px": b.residuals_px, "inliers": b.inliers,
            "covariance": unc.covariance, "sigma_px": b.sigma_px,
            "outliers": [vars(o) for o in b.outliers],
            "cross_validation": vars(result.cross_validation)}


def _assert_identical(first: dict, second: dict) -> None:
    for key, value in first.items():
        if isinstance(value, np.ndarray):
            assert np.array_equal(value, second[key], equal_nan=True), key
        else:
            assert value == second[key], key


def test_calibrating_twice_in_one_process_is_bit_identical(cube_views):
    obs, target = cube_views
    runs = [_outputs(calibrate(obs, target, "opencv5")) for _ in range(2)]
    assert runs[0]["cross_validation"] is not None
    _assert_identical(*runs)


def _copies_in_identity_order(poses: list, ascending: bool, copies: int = 32) -> list:
    """Equal copies of ``poses`` whose ``id()`` rises (or falls) along the list.

    The copies are made interleaved and one per pose is picked greedily; the test checks the order.
    """
    pool = [[RigidTransform.from_matrix(p.as_matrix()) for p in poses] for _ in range(copies)]
    by_pose = [sorted((row[k] for row in pool), key=id, reverse=not ascending) for k in range(len(poses))]
    picked, bound = [], None
    for candidates in by_pose:
        beyond = [c for c in candidates if bound is None or (id(c) > bound if ascending else id(c) < bound)]
        picked.append(beyond[0])
        bound = id(beyond[0])
    return picked


def test_spanning_tree_ties_do_not_depend_on_object_identity():
    """Two cameras x two shots, every view with the same point count and view poses that do not
    close the loop exactly: the tree (and so the initial poses) must not follow memory addresses."""
    rng = np.random.default_rng(8)
    keys = [(0, 0), (0, 1), (1, 0), (1, 1)]
    poses = [RigidTransform.from_rvec_tvec(rng.normal(scale=0.3, size=3), rng.normal(size=3)) for _ in keys]
    names = SimpleNamespace(camera_names=["cam0", "cam1"], shot_names=["s0", "s1"])
    results = []
    for ascending in (True, False):
        objects = _copies_in_identity_order(poses, ascending)
        assert np.all(np.diff([id(o) for o in objects]) > 0) == ascending
        cam_from_world, world_from_target, _ = _spanning_tree(
            {key: (pose, 50) for key, pose in zip(keys, objects)}, names)
        results.append(np.stack([p.as_matrix() for p in [*cam_from_world, *world_from_target]]))
    assert np.array_equal(*results)


def _without_date(text: str) -> str:
    """rig.toml without the lines that record when it was written (its only legitimate difference)."""
    return "\n".join(line for line in text.splitlines() if not line.startswith(DATE_LINES))


@pytest.mark.slow
def test_two_cli_runs_write_identical_files(cube_views, tmp_path):
    """Two ``scanrig calibrate --corners`` processes on one session write the same bytes."""
    obs, target = cube_views
    save_target(target, tmp_path / "target.toml")
    for name, (width, height) in obs.image_sizes.items():   # the CLI reads the image sizes from these
        (tmp_path / "calibration" / name).mkdir(parents=True)
        write_image(tmp_path / "calibration" / name / f"{obs.shot_names[0]}.png", np.zeros((height, width), np.uint8))
    write_corners_csv(obs, tmp_path / "corners.csv")
    written = []
    for _ in range(2):
        subprocess.run([sys.executable, "-m", "scanrig", "calibrate", str(tmp_path), "--corners",
                        str(tmp_path / "corners.csv"), "--no-plots"], check=True, capture_output=True)
        written.append({"rig.toml": _without_date((tmp_path / "rig.toml").read_text())}
                       | {name: (tmp_path / REPORT_DIR / name).read_bytes()
                          for name in ("summary.txt", "outliers.csv", "corners.csv")})
    assert written[0] == written[1]
