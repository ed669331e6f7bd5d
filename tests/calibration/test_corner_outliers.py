"""Rendered cube sessions of the built-in scene calibrate without systematic corner errors.

The simulator once averaged a regular 4 x 4 grid of point samples per edge pixel and blurred the
pixel grid afterwards: a printed edge along a pixel axis was then placed in steps of 1/4 px and
a blurred-edge fit moved it by up to 0.1 px with its sub-pixel phase, the same for every corner
of a board seen square-on. On the built-in scene 6-7 % of the corners were rejected as
outliers, in one camera as a regular grid over one board. Here the built-in scene's rig and cube
are rendered as ``scanrig simulate`` renders them (half-size images, as the quick demo), the
corners detected and calibrated, and the residuals checked three ways:

- the share of corners rejected as outliers is at most 1 %;
- residuals binned by the sub-pixel phase of the corner (4 x 4 bins of ``(u, v) - round(u, v)``,
  where the old renderer's error lived): no bin's mean beyond ``PHASE_Z`` standard errors;
- a Moran's-I-like check: in every board view, the residuals of corners next to each other
  along a board axis are neither alike nor opposed more often than chance allows (a sign test
  per view and axis, Bonferroni-corrected to a family-wise level ``ALPHA``).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from scanrig.calibration.pipeline import calibrate, detect_session
from scanrig.io.session import Session
from scanrig.sim import load_scene
from scanrig.sim.calibration_shots import write_calibration
from scanrig.sim.scan_setup import scene_rig
from scanrig.targets import load_target

#: Cube poses rendered (shot 000 is the cube at the world origin, faces along the pixel axes).
N_SHOTS = 4
#: The acceptance bound on the share of corners rejected as outliers.
MAX_REJECTED_FRACTION = 0.01
#: Sub-pixel phase bins per axis.
PHASE_BINS = 4
#: Bound on a phase bin's mean residual in standard errors (sigma / sqrt(n)); 2 x 16 bins at
#: 4.5 sigma give a family-wise false alarm of 2e-4 for Gaussian residuals.
PHASE_Z = 4.5
#: Family-wise false-alarm level of the per-view neighbour sign tests.
ALPHA = 1e-3
#: Fewest neighbour pairs of a board view and axis that enter the sign test.
MIN_PAIRS = 10


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    root = tmp_path_factory.mktemp("builtin")
    (root / "truth").mkdir()
    scene = load_scene("default")
    rig = scene_rig(scene, 3, 0.5)
    write_calibration(root, scene, rig, N_SHOTS, "cube", np.random.default_rng(0), workers=2)
    target = load_target(root / "target.toml")
    obs, _ = detect_session(Session(root), target)
    return obs, target, calibrate(obs, target, cross_validate=False)


@pytest.mark.slow
def test_few_corners_are_rejected(calibrated):
    obs, _, result = calibrated
    assert len(obs.point_id) > 300
    assert len(result.bundle.outliers) <= MAX_REJECTED_FRACTION * len(obs.point_id)


def _usable_residuals(obs, result):
    """Residuals (n, 2), detections (n, 2) and rows of every corner the bundle could use, outliers too."""
    residuals = result.bundle.residuals_px
    rows = np.flatnonzero(np.all(np.isfinite(residuals), axis=1))
    return residuals[rows], obs.uv[rows], rows


def phase_z(obs, result) -> np.ndarray:
    """(bins, 2) mean residual of each sub-pixel phase bin in standard errors (sigma / sqrt(n))."""
    residuals, uv, _ = _usable_residuals(obs, result)
    phase = uv - np.round(uv)                                       # [-0.5, 0.5]
    cell = np.clip(np.floor((phase + 0.5) * PHASE_BINS).astype(np.int64), 0, PHASE_BINS - 1)
    bins = cell[:, 0] * PHASE_BINS + cell[:, 1]
    sigma = result.bundle.sigma_px
    return np.array([residuals[bins == b].mean(axis=0) / (sigma / np.sqrt(np.sum(bins == b)))
                     for b in np.unique(bins)])


def neighbour_p_values(obs, target, result) -> np.ndarray:
    """Two-sided sign-test p-values, one per board view and board axis with at least
    :data:`MIN_PAIRS` pairs, of the residual products of corners next to each other along that
    axis: without a pattern a product is positive or negative with equal chance (noise is
    independent from corner to corner); a row of corners that shares an error makes them alike
    (positive), an error alternating from corner to corner makes them negative. Signs, not sizes,
    so that a single gross outlier does not decide."""
    residuals, _, rows = _usable_residuals(obs, result)
    ids = obs.point_id[rows]
    board = target.board_of(ids)
    view = (obs.camera[rows] * len(obs.shot_names) + obs.shot[rows]) * len(target.boards) + board
    cols = target.boards[0].squares[0] - 1
    local = ids - np.array([b.id_offset for b in target.boards])[board]
    index = {(int(v), int(k // cols), int(k % cols)): i for i, (v, k) in enumerate(zip(view, local))}
    p_values = []
    for dr, dc in ((0, 1), (1, 0)):
        pairs = [(v, i, index[(v, r + dr, c + dc)]) for (v, r, c), i in index.items() if (v, r + dr, c + dc) in index]
        pairs = np.array(pairs)
        positive = np.einsum("ij,ij->i", residuals[pairs[:, 1]], residuals[pairs[:, 2]]) > 0
        for v in np.unique(pairs[:, 0]):
            here = positive[pairs[:, 0] == v]
            if len(here) >= MIN_PAIRS:
                p_values.append(stats.binomtest(int(here.sum()), len(here), 0.5).pvalue)
    return np.array(p_values)


@pytest.mark.slow
def test_no_residual_pattern_over_the_sub_pixel_phase(calibrated):
    obs, _, result = calibrated
    z = phase_z(obs, result)
    assert len(z) == PHASE_BINS ** 2
    assert np.all(np.abs(z) <= PHASE_Z), z


@pytest.mark.slow
def test_neighbouring_corners_have_uncorrelated_residuals(calibrated):
    """Within each board view, the residuals of corners next to each other along a board axis
    (a row of one phase, as the old renderer's grid of outliers) are not alike."""
    p_values = neighbour_p_values(*calibrated)
    assert len(p_values) >= 10
    assert p_values.min() >= ALPHA / len(p_values), np.sort(p_values)[:3]
