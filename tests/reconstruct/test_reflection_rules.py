"""Spot correspondence on shiny parts: a second lit point, and fixed features that are not laser light.

On a rendered shiny part (``scanrig simulate --scene shiny``) a secondary reflection that lands on
a matte surface is a real spot: every camera that sees it agrees on it, and it is often seen by
more cameras than the beam's own hit on the dark polished metal. Picking the hypothesis with the
most views then output the reflection as the frame's point; the frame is now flagged ambiguous.
Faint glints of room light on polished metal are detected at the same pixel frame after frame; two
of them can be epipolar-consistent by chance and must neither make a frame ambiguous nor a point.
"""

import numpy as np
import pyarrow as pa

from scanrig.reconstruct.candidates import STATIC_MIN_FRAMES, fixed_features, spot_candidates
from scanrig.reconstruct.correspondence import FrameStatus, match_spots
from scanrig.reconstruct.flags import Flag
from scanrig.reconstruct.spots import reconstruct_spots
from tests.reconstruct.synth import points_in_cube, ring_rig, two_camera_table

SIGMA_PX = 0.3


def _table(frames_uv, sigma_px=SIGMA_PX):
    """Spot traces of several frames: ``[{camera: (n, 2) pixels in rank order}, ...]`` -> f0, f1, ..."""
    tables = []
    for k, uv in enumerate(frames_uv):
        uv = {cam: q for cam, q in uv.items() if len(q)}
        if not uv:
            continue
        t = two_camera_table(uv, sigma_px)
        tables.append(t.set_column(t.schema.get_field_index("frame"), "frame",
                                   pa.array([f"f{k}"] * len(t), pa.string())))
    return pa.concat_tables(tables)


def _noisy(cam, p, rng):
    return cam.project(np.atleast_2d(p)) + rng.normal(0.0, SIGMA_PX, (len(np.atleast_2d(p)), 2))


def test_a_reflection_seen_by_more_cameras_than_the_spot_is_not_chosen():
    """Spot P in cam0 and cam1; its reflection S (a lit matte point) in all three cameras."""
    rng = np.random.default_rng(41)
    rig = ring_rig()
    cam0, cam1, cam2 = rig.cameras
    p, s = np.array([0.02, 0.0, 0.05]), np.array([-0.06, -0.05, -0.1])
    uv = {cam0.name: _noisy(cam0, [p, s], rng), cam1.name: _noisy(cam1, [s, p], rng),
          cam2.name: _noisy(cam2, s, rng)}
    table = _table([uv])
    matches = match_spots(rig, spot_candidates(table, rig.names, ["f0"]))
    assert matches.status[0] == FrameStatus.AMBIGUOUS and matches.flags[0] & Flag.AMBIGUOUS
    cloud, summary, _ = reconstruct_spots(rig, table, ["f0"])
    assert len(cloud) == 0 and summary["frames_ambiguous"] == 1


def test_a_reflection_seen_by_one_camera_is_dropped_and_the_spot_kept():
    """The same frame when only cam2 sees the reflection: one lit point seen by two cameras or more."""
    rng = np.random.default_rng(42)
    rig = ring_rig()
    cam0, cam1, cam2 = rig.cameras
    p, s = np.array([0.02, 0.0, 0.05]), np.array([-0.06, -0.05, -0.1])
    uv = {cam0.name: _noisy(cam0, p, rng), cam1.name: _noisy(cam1, p, rng), cam2.name: _noisy(cam2, [s, p], rng)}
    cloud, summary, matches = reconstruct_spots(rig, _table([uv]), ["f0"])
    assert summary["frames_matched"] == 1 and matches.choice[0].tolist() == [0, 0, 1]
    # 3-D sigma at 0.3 px + 0.1 px floor is ~0.2 mm; 1 mm is > 4 sigma
    assert np.linalg.norm(cloud.p_world[0] - p) < 1e-3


def test_fixed_features_are_never_matched():
    """A glint at a fixed 3-D point G, seen by cam0 and cam2 in every frame (so epipolar-consistent),
    besides a moving spot: the glint neither makes frames ambiguous nor gives a point of its own."""
    rng = np.random.default_rng(43)
    rig = ring_rig()
    g = np.array([0.1, 0.12, 0.1])
    spots = points_in_cube(rng, 8)
    frames_uv = []
    for k, p in enumerate(spots):
        uv = {cam.name: _noisy(cam, p, rng) for cam in rig.cameras}
        for i in (0, 2):  # the glint: fainter, so ranked after the spot
            uv[rig.cameras[i].name] = np.vstack([uv[rig.cameras[i].name], _noisy(rig.cameras[i], g, rng)])
        frames_uv.append(uv)
    # a last frame in which the beam is hidden: only the glint is seen
    frames_uv.append({rig.cameras[i].name: _noisy(rig.cameras[i], g, rng) for i in (0, 2)})
    frames = [f"f{k}" for k in range(len(frames_uv))]
    table = _table(frames_uv)
    cloud, summary, matches = reconstruct_spots(rig, table, frames)
    assert summary["n_candidates_static"] == 2 * len(frames)
    assert summary["frames_matched"] == len(spots) and summary["frames_ambiguous"] == 0
    assert matches.status[-1] == FrameStatus.TOO_FEW_CAMERAS
    assert np.all(np.linalg.norm(cloud.p_world - spots, axis=1) < 1e-3)
    # without the test the glint pair is a second lit point in every frame, and the last frame's point
    cand = spot_candidates(table, rig.names, frames, static_min_frames=0)
    loose = match_spots(rig, cand)
    assert np.all(loose.status[:-1] == FrameStatus.AMBIGUOUS) and loose.status[-1] == FrameStatus.MATCHED


def test_fixed_features_need_the_minimum_number_of_other_frames():
    uv = np.array([[100.0, 200.0]] * (STATIC_MIN_FRAMES + 1) + [[500.0, 500.0]] * STATIC_MIN_FRAMES)
    frame = np.r_[np.arange(STATIC_MIN_FRAMES + 1), np.arange(STATIC_MIN_FRAMES)]
    camera = np.zeros(len(uv), np.int64)
    static = fixed_features(uv + 0.3, camera, frame, 1.5, STATIC_MIN_FRAMES)
    assert static[: STATIC_MIN_FRAMES + 1].all() and not static[STATIC_MIN_FRAMES + 1:].any()
    # the same pixel twice in one frame, or in another camera, does not count
    same_frame = fixed_features(uv[:2], camera[:2], np.zeros(2, np.int64), 1.5, 1)
    other_cam = fixed_features(uv[:2], np.array([0, 1]), np.array([0, 1]), 1.5, 1)
    assert not same_frame.any() and not other_cam.any()


def _raster(rng, pitch_px, n_u, n_v, origin=(300.0, 200.0)):
    """One spot per frame on a raster of ``pitch_px`` in the image (a fine scan), detection noise 0.05 px."""
    gv, gu = np.meshgrid(np.arange(n_v), np.arange(n_u), indexing="ij")
    uv = np.c_[gu.ravel(), gv.ravel()] * pitch_px + origin
    return uv + rng.normal(0.0, 0.05, uv.shape)


def test_a_scan_finer_than_the_radius_is_not_a_fixed_feature_but_a_glint_is():
    # 0.2 mm pitch at 1 m is ~0.3 px: every spot has a dozen other frames' spots within 1.5 px,
    # which a count alone would call a fixed feature. A glint is a spike: its recurrences sit at
    # one place (a faint one scatters by its centre sigma, up to 1 px), not spread like the scan's.
    rng = np.random.default_rng(44)
    for uv in (_raster(rng, 0.3, 60, 40), _raster(rng, 0.2, 400, 1)):  # a raster, one scan line
        n = len(uv)
        glint = np.array([420.0, 260.0]) + rng.normal(0.0, 0.3, (12, 2))
        wander = np.array([460.0, 280.0]) + rng.normal(0.0, 0.8, (12, 2))  # a faint one: sigma ~1 px
        frames = np.r_[np.arange(n), rng.choice(n, 12, replace=False), rng.choice(n, 12, replace=False)]
        all_uv = np.vstack([uv, glint, wander])
        static = fixed_features(all_uv, np.zeros(len(all_uv), np.int64), frames, 1.5, STATIC_MIN_FRAMES)
        assert not static[:n].any()
        assert static[n : n + 12].all()
        assert static[n + 12 :].sum() >= 11  # a centre ~2.5 sigma out can fall outside both scales
        # a count of recurrences within the radius alone marks the scan
        near = np.hypot(*(uv[:, None, :] - uv[None, :, :]).transpose(2, 0, 1)) < 1.5
        assert np.median(near.sum(axis=1) - 1) > 2 * STATIC_MIN_FRAMES
