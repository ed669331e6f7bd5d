"""Detection on a session rendered by ``scanrig.sim``: candidates land on the true hit points."""

import csv

import numpy as np
import pyarrow.compute as pc
import pytest

import scanrig
from scanrig.laser.session_detect import detect_session

# The simulator renders the spot footprint on inclined surfaces with speckle and lens blur, so the
# intensity centroid differs from the projected beam hit by up to about 0.1 px; 0.3 px is three
# times that, far below the ~5 px of any wrong match.
MATCH_TOL_PX = 0.3
STRONG_SNR = 20.0


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    sim = pytest.importorskip("scanrig.sim.session_writer")
    root = tmp_path_factory.mktemp("sim_spot")
    sim.simulate_session(root, n_cameras=2, mode="spot", n_frames=8, rng=np.random.default_rng(601),
                         with_calibration=False, workers=1)
    return root


@pytest.mark.slow
def test_strong_candidates_are_the_projected_truth(simulated):
    table = detect_session(simulated)  # laser_color = "red" and the dark frames come from the session
    rig = scanrig.load_rig(simulated / "truth" / "rig.toml")
    with open(simulated / "truth" / "frames.csv") as f:
        truth = [r for r in csv.DictReader(f) if r["kind"] == "primary"]
    matched = 0
    for cam in rig.names:
        rows = table.filter(pc.and_(pc.equal(table["camera"], cam), pc.greater_equal(table["snr"], STRONG_SNR)))
        for r in truth:
            q = rig[cam].project(np.array([[float(r[k]) for k in "xyz"]]))[0]
            det = rows.filter(pc.equal(rows["frame"], r["frame"]))
            if len(det) == 0:
                continue  # outside the image or hidden from this camera
            d = np.hypot(det["u"].to_numpy() - q[0], det["v"].to_numpy() - q[1])
            assert d.min() < MATCH_TOL_PX, (cam, r["frame"], d.min())
            assert det["rank"].to_numpy()[np.argmin(d)] == 0
            matched += 1
    assert matched >= 4
