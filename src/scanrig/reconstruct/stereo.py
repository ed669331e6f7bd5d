"""Passive-stereo baseline: OpenCV semi-global matching on rectified pairs of the same rig.

The source compares its active method with stereo on the same scene; this module gives that
comparison with no extra calibration: each camera pair of the rig is rectified
(``cv2.stereoRectify`` with the rig's intrinsics, distortion and relative pose), matched with
``cv2.StereoSGBM`` and the disparities turned into world points. On a laser session the laser-off
frames (``scan/<camera>/dark.<ext>``) show the scene's texture under ambient light.
"""

from __future__ import annotations

import numpy as np

from scanrig.errors import InputError

#: SGBM block size (odd, pixels) and its smoothness penalties per OpenCV's recommendation.
BLOCK_SIZE = 5
#: Left–right consistency and uniqueness checks of SGBM (OpenCV's documented defaults region).
DISP12_MAX_DIFF = 1
UNIQUENESS_RATIO = 10
#: Largest disparity search SGBM is asked for (memory grows with width x height x disparities).
MAX_DISPARITIES = 512


def _grey8(img: np.ndarray) -> np.ndarray:
    if img.ndim == 3:
        img = img.mean(axis=2)
    img = img.astype(np.float64)
    top = np.percentile(img, 99.5)
    return np.clip(img * (255.0 / max(top, 1e-9)), 0, 255).astype(np.uint8)


def stereo_pair_points(cam_a, cam_b, img_a: np.ndarray, img_b: np.ndarray,
                       depth_range_m: tuple[float, float] = (0.5, 2.0)) -> np.ndarray:
    """World points from one camera pair by rectification and semi-global matching.

    Parameters
    ----------
    cam_a, cam_b : Camera
        Calibrated cameras of the same rig (roughly side by side).
    img_a, img_b : ndarray of shape (H, W) or (H, W, 3)
        Simultaneous images, 8- or 16-bit.
    depth_range_m : (float, float)
        Nearest and farthest depth searched, metres (sets the disparity range).

    Returns
    -------
    ndarray of shape (N, 3)
        Points with a valid disparity, world frame, metres.

    Raises
    ------
    InputError
        If the image sizes disagree with the cameras or the pair is stacked vertically (SGBM
        searches along rows only).
    """
    import cv2

    for cam, img in ((cam_a, img_a), (cam_b, img_b)):
        if img.shape[:2] != (cam.height, cam.width):
            raise InputError(f"image for camera {cam.name!r} is {img.shape[1]}x{img.shape[0]}, "
                             f"the camera is {cam.width}x{cam.height}")
    b_from_a = cam_b.cam_from_world @ cam_a.cam_from_world.inverse()
    if b_from_a.t[0] > 0:  # camera b is to the left of a: swap so that disparities are positive
        return stereo_pair_points(cam_b, cam_a, img_b, img_a, depth_range_m)
    if abs(b_from_a.t[1]) > abs(b_from_a.t[0]):
        raise InputError(f"cameras {cam_a.name!r} and {cam_b.name!r} are stacked vertically; "
                         "semi-global matching needs a side-by-side pair")
    size = (cam_a.width, cam_a.height)
    # flags=0: keep each view's principal point, so converging cameras still overlap after rectification
    R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(cam_a.K, cam_a.dist, cam_b.K, cam_b.dist, size,
                                                b_from_a.R.copy(), b_from_a.t.reshape(3, 1).copy(), flags=0,
                                                alpha=0)
    maps = [cv2.initUndistortRectifyMap(cam.K, cam.dist, R, P, size, cv2.CV_32FC1)
            for cam, R, P in ((cam_a, R1, P1), (cam_b, R2, P2))]
    rect = [cv2.remap(_grey8(img), mx, my, cv2.INTER_LINEAR) for img, (mx, my) in zip((img_a, img_b), maps)]
    # disparity of depth Z: d = f·B / Z + (cx_a − cx_b), with f·B = −P2[0, 3]
    f_b, shift = -P2[0, 3], P1[0, 2] - P2[0, 2]
    d_min = int(np.floor(f_b / depth_range_m[1] + shift))
    n_disp = int(np.ceil((f_b / depth_range_m[0] + shift - d_min) / 16.0)) * 16
    if n_disp > MAX_DISPARITIES or d_min + n_disp >= cam_a.width:
        raise InputError(f"cameras {cam_a.name!r} and {cam_b.name!r}: depths {depth_range_m} m need disparities "
                         f"{d_min}..{d_min + n_disp} px; the baseline is too wide for semi-global matching "
                         "(narrow the depth range or use a closer pair)")
    sgbm = cv2.StereoSGBM_create(minDisparity=d_min, numDisparities=max(n_disp, 16), blockSize=BLOCK_SIZE,
                                 P1=8 * BLOCK_SIZE**2, P2=32 * BLOCK_SIZE**2, disp12MaxDiff=DISP12_MAX_DIFF,
                                 uniquenessRatio=UNIQUENESS_RATIO, speckleWindowSize=100, speckleRange=2,
                                 mode=cv2.STEREO_SGBM_MODE_SGBM)
    disparity = sgbm.compute(rect[0], rect[1]).astype(np.float32) / 16.0
    valid = disparity > d_min
    xyz_rect = cv2.reprojectImageTo3D(disparity, Q)[valid].astype(np.float64)
    p_cam_a = xyz_rect @ R1  # rectified -> camera a (R1 maps camera a into the rectified frame)
    return cam_a.cam_from_world.inverse().apply(p_cam_a)


def stereo_rig_points(rig, images: dict, depth_range_m: tuple[float, float] = (0.5, 2.0)) -> np.ndarray:
    """Points of every neighbouring pair of the rig (in rig order) that sits side by side.

    Parameters
    ----------
    rig : Rig
    images : dict
        ``camera name -> image`` taken at the same instant.
    depth_range_m : (float, float)

    Returns
    -------
    ndarray of shape (N, 3)
        All pairs' points, world frame.
    """
    names = [n for n in rig.names if n in images]
    if len(names) < 2:
        raise InputError(f"stereo needs images of 2 or more cameras, got {names}")
    clouds = []
    for a, b in zip(names[:-1], names[1:]):
        clouds.append(stereo_pair_points(rig[a], rig[b], images[a], images[b], depth_range_m))
    return np.concatenate(clouds)
