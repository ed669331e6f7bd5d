"""The stripe of a light-plane image is taken only inside the target's outline."""

import numpy as np

from scanrig.geometry import RigidTransform
from scanrig.reconstruct.light_plane_session import board_outlines, inside_polygon, points_on_target, stripe_pixels
from scanrig.targets import chessboard
from tests.reconstruct import light_plane_synth as synth


def _board_facing_camera(z_m=0.4, tilt_rad=0.3):
    """A 9 x 6 chessboard (0.36 x 0.27 m with margins) centred on the optical axis, tilted about y."""
    target = chessboard(inner_corners=(9, 6), square_m=0.03)
    w, h = target.boards[0].size_m
    c, s = np.cos(tilt_rad), np.sin(tilt_rad)
    R = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return target, RigidTransform(R, np.array([0.0, 0.0, z_m]) - R @ [w / 2, h / 2, 0.0])


def test_inside_polygon():
    square = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]])
    q = np.array([[5.0, 5.0], [-1.0, 5.0], [5.0, 11.0], [9.9, 0.1]])
    np.testing.assert_array_equal(inside_polygon(q, square), [True, False, False, True])


def test_stripe_only_inside_the_board():
    cam = synth.camera()
    target, pose = _board_facing_camera()
    (k, polygon), = board_outlines(cam, target, pose)
    # a bright vertical line over the whole image height: the board covers only part of it
    u = np.arange(synth.WIDTH)
    row = 10.0 + 150.0 * np.exp(-0.5 * (u - 700.3) ** 2 / 1.2**2)
    image = np.rint(np.tile(row, (synth.HEIGHT, 1))).astype(np.uint8)
    q, board = stripe_pixels(cam, target, pose, image, None, "grey")
    inside = inside_polygon(np.c_[np.full(synth.HEIGHT, 700.3), np.arange(synth.HEIGHT)], polygon)
    assert k == 0 and np.all(board == 0)
    assert np.all(inside_polygon(q, polygon))
    assert abs(len(q) - inside.sum()) <= 2  # every board row but the outline's own edge rows
    assert np.abs(q[:, 0] - 700.3).max() < 0.05
    # the points lie on the board's plane
    p = points_on_target(cam, target, pose, q, board)
    normal = pose.R[:, 2]
    np.testing.assert_allclose(p @ normal, normal @ pose.t, atol=1e-9)


def test_board_facing_away_gives_no_outline():
    cam = synth.camera()
    target, pose = _board_facing_camera()
    flipped = pose @ RigidTransform(np.diag([1.0, -1.0, -1.0]), np.zeros(3))
    assert board_outlines(cam, target, flipped) == []
    q, board = stripe_pixels(cam, target, flipped, np.zeros((synth.HEIGHT, synth.WIDTH), np.uint8), None, "grey")
    assert q.shape == (0, 2) and board.shape == (0,)
