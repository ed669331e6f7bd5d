"""Spot correspondence: reflection rejection, ambiguity, frames no pair agrees on."""

import numpy as np
import pytest

from scanrig.errors import InputError
from scanrig.geometry import Rig
from scanrig.reconstruct.candidates import frame_order, spot_candidates
from scanrig.reconstruct.correspondence import FrameStatus, hypotheses, match_spots
from scanrig.reconstruct.flags import Flag
from scanrig.reconstruct.spots import reconstruct_spots
from tests.reconstruct.synth import points_in_cube, reflection_outcome, ring_rig, spot_traces, two_camera_table

#: Detection noise of the synthetic traces (the brief's 0.3 px).
SIGMA_PX = 0.3
#: Acceptance figures of issue 6 (four cameras, reflections in >= 20 % of frames).
MIN_REJECTED_REFLECTIONS = 0.95
MAX_FRACTION_BEYOND_1MM = 0.005
#: Outlier distance of the acceptance, metres; with 0.3 px noise the 3-D sigma is ~0.2 mm, so
#: a correct point lies beyond 1 mm with probability ~1e-6.
OUTLIER_M = 1e-3


def test_reflections_are_rejected_with_four_cameras():
    rng = np.random.default_rng(31)
    rig = ring_rig((-60.0, -20.0, 20.0, 60.0))
    p_true = points_in_cube(rng, 600)
    table, truth = spot_traces(rig, p_true, rng, SIGMA_PX, reflection_rate=0.3, occlusion_rate=0.1)
    frames = frame_order(table)
    cloud, summary, matches = reconstruct_spots(rig, table, frames)
    n_refl, rejected = reflection_outcome(rig, frames, truth, matches)
    frames_with_reflection = len({f for (_, f), r in truth.items() if r.any()}) / len(frames)
    assert frames_with_reflection >= 0.2
    assert rejected / n_refl >= MIN_REJECTED_REFLECTIONS
    err = np.linalg.norm(cloud.p_world - p_true[cloud.frame], axis=1)
    assert np.mean(err > OUTLIER_M) < MAX_FRACTION_BEYOND_1MM
    assert summary["frames_matched"] >= 0.95 * len(frames)
    assert np.any(cloud.flags & Flag.REJECTED_CANDIDATES)


def test_clean_frames_match_every_view():
    rng = np.random.default_rng(32)
    rig = ring_rig()
    p_true = points_in_cube(rng, 300)
    table, _ = spot_traces(rig, p_true, rng, SIGMA_PX)
    cloud, summary, matches = reconstruct_spots(rig, table, frame_order(table))
    assert summary["frames_matched"] == 300 and len(cloud) == 300
    assert np.all(cloud.n_views == 3) and np.all(cloud.flags == 0)
    assert np.all(matches.choice == 0)
    z = np.linalg.solve(np.linalg.cholesky(matches.info.cov), (cloud.p_world - p_true)[..., None])[..., 0]
    # 900 whitened components: standard error of their std is 0.024; the floor of 0.1 px added
    # to 0.3 px inflates sigma by sqrt(1 + 1/9) = 1.054, so the spread is ~0.95.
    assert 0.85 < z.std() < 1.05


def test_two_equally_good_pairings_are_flagged_not_guessed():
    rig = Rig(ring_rig().cameras[:2])
    p = np.array([[0.05, 0.0, 0.0], [-0.05, 0.02, 0.05]])
    uv = {cam.name: cam.project(p) for cam in rig.cameras}
    table = two_camera_table(uv)
    cand = spot_candidates(table, rig.names, ["f0"])
    matches = match_spots(rig, cand)
    assert matches.status[0] == FrameStatus.AMBIGUOUS
    assert matches.flags[0] & Flag.AMBIGUOUS
    cloud, summary, _ = reconstruct_spots(rig, table, ["f0"])
    assert len(cloud) == 0 and summary["frames_ambiguous"] == 1
    cloud, _, _ = reconstruct_spots(rig, table, ["f0"], keep_ambiguous=True)
    assert len(cloud) == 1 and cloud.flags[0] & Flag.AMBIGUOUS


def test_a_frame_no_pair_agrees_on_is_counted():
    rig = Rig(ring_rig().cameras[:2])
    cam0, cam1 = rig.cameras
    uv = {cam0.name: cam0.project(np.array([[0.05, 0.0, 0.0]])),
          cam1.name: cam1.project(np.array([[0.0, 0.0, 0.1]]))}
    table = two_camera_table(uv)
    cloud, summary, matches = reconstruct_spots(rig, table, ["f0", "f1"])
    assert matches.status.tolist() == [FrameStatus.NO_AGREEMENT, FrameStatus.TOO_FEW_CAMERAS]
    assert summary["frames_no_agreement"] == 1 and summary["frames_too_few_cameras"] == 1
    assert len(cloud) == 0 and np.isnan(matches.p_world).all()


def test_hypotheses_enumerate_every_choice_of_two_or_more_cameras():
    for n_cams, k in [(2, 1), (3, 2), (4, 3)]:
        hyp = hypotheses(n_cams, k)
        assert len(hyp) == (k + 1) ** n_cams - 1 - n_cams * k
        assert len({tuple(h) for h in hyp}) == len(hyp)
        assert np.all((hyp >= 0).sum(axis=1) >= 2)


def test_candidates_keep_the_brightest_and_count_the_rest():
    rig = Rig(ring_rig().cameras[:2])
    uv = {rig.names[0]: np.arange(12.0).reshape(6, 2), rig.names[1]: [[1.0, 2.0]]}
    cand = spot_candidates(two_camera_table(uv), rig.names, ["f0"], max_per_camera=4)
    assert cand.count.tolist() == [[4, 1]] and cand.n_ignored == 2
    np.testing.assert_array_equal(cand.q[0, 0, :, 0], [0.0, 2.0, 4.0, 6.0])


def test_bad_input_is_named():
    rig = ring_rig()
    table = two_camera_table({"camX": [[1.0, 2.0]]})
    with pytest.raises(InputError, match=r"traces name cameras \['camX'\] that are not in the rig "
                                         r"\(cameras: \['cam0', 'cam1', 'cam2'\]\)"):
        spot_candidates(table, rig.names, ["f0"])
    single = Rig(rig.cameras[:1])
    cand = spot_candidates(two_camera_table({"cam0": [[1.0, 2.0]]}), single.names, ["f0"])
    with pytest.raises(InputError, match="multi-view reconstruction needs at least 2 cameras, the rig has 1"):
        match_spots(single, cand)
    cand = spot_candidates(two_camera_table({"cam0": [[1.0, 2.0]]}), rig.names, ["f0"])
    with pytest.raises(InputError, match=r"gate_probability must be in \(0, 1\), got 1.5"):
        match_spots(rig, cand, gate_probability=1.5)
