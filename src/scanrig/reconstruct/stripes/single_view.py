"""Single-view stripe points: detections seen by one camera only, intersected with the light plane."""

from __future__ import annotations

import numpy as np

from scanrig.geometry.uncertainty import sigma_from_covariance
from scanrig.reconstruct.flags import Flag
from scanrig.reconstruct.light_plane import intersect_plane, ray_plane_covariance
from scanrig.reconstruct.points import PointCloud

#: A single-view point is kept only if its sigma is at most this multiple of the median sigma of
#: the frame's multi-view points: rays that meet the light plane at a grazing angle add nothing.
SINGLE_VIEW_SIGMA_RATIO = 3.0


def single_view_points(cams, views, plane, crossed, used, sigma_ref: float, frame_index: int):
    """The frame's single-view points (flag ``PLANE_SINGLE_VIEW``), camera by camera.

    A detection qualifies when it is the brightest on its line, has no crossing in any other
    camera (seen by this camera only) and lies on a piece of stripe that other cameras confirm
    elsewhere (an isolated noise peak, or a reflection seen by this camera only, is not part of
    one); its ray is intersected with the plane, and the point kept when its sigma is at most
    :data:`SINGLE_VIEW_SIGMA_RATIO` times ``sigma_ref``.

    Parameters
    ----------
    cams : list of Camera
        The rig's cameras, in the order of ``views``.
    views : list of StripeView
        The frame's detections per camera.
    plane : Plane
        The frame's light plane, with its position uncertainty.
    crossed : list of ndarray of shape (n_c,), bool
        Per camera: detections with a crossing in another camera.
    used : ndarray of shape (sum n_c,), bool
        Detections (frame-wide ids, cameras in order) that belong to an accepted multi-view point.
    sigma_ref : float
        Median sigma of the frame's multi-view points, metres.
    frame_index : int
        Written in the ``frame`` column.

    Returns
    -------
    cloud : PointCloud
    cov : ndarray of shape (M, 3, 3)
        The points' covariances, m².
    """
    offsets = np.cumsum([0] + [len(v.q) for v in views])
    clouds, covs = [], [np.zeros((0, 3, 3))]
    for i, view in enumerate(views):
        n_i = len(view.q)
        if n_i == 0:
            continue
        mine = used[offsets[i]:offsets[i + 1]]
        confirmed = np.zeros(n_i, bool)
        confirmed[np.unique(view.piece[mine])] = True
        lone = (~crossed[i] & (view.rank == 0) & ~mine & confirmed[view.piece]
                & np.all(np.isfinite(view.dirs), axis=1))
        if not lone.any():
            continue
        centers = np.repeat(cams[i].center_world[None], lone.sum(), axis=0)
        p1, t1 = intersect_plane(centers, view.dirs[lone], plane)
        fin = np.all(np.isfinite(p1), axis=1)
        focal = np.sqrt(cams[i].params[0] * cams[i].params[1])
        sig_px = np.sqrt(0.5 * np.trace(view.cov[lone], axis1=1, axis2=2))
        cov1 = ray_plane_covariance(view.dirs[lone][fin], t1[fin], sig_px[fin] / focal, plane, p1[fin])
        sigma1 = sigma_from_covariance(cov1)
        sharp = sigma1 <= SINGLE_VIEW_SIGMA_RATIO * sigma_ref
        flags1 = np.full(sharp.sum(), Flag.PLANE_SINGLE_VIEW, np.uint16)
        flags1[view.saturated[lone][fin][sharp]] |= np.uint16(Flag.SATURATED)
        clouds.append(PointCloud(p1[fin][sharp], sigma1[sharp], np.ones(sharp.sum()),
                                 np.full(sharp.sum(), np.nan), np.full(sharp.sum(), frame_index), flags1))
        covs.append(cov1[sharp])
    return PointCloud.concatenate(clouds), np.concatenate(covs)
