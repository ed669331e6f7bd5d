"""Light-plane calibration from a session's ``light_plane/<camera>/`` images.

Each laser-on image shows the calibration target at a pose known from the calibration (the
caller supplies ``world_from_target``), crossed by the fixed laser's stripe. The stripe's centres
(:func:`scanrig.detect_stripe`, the brightest peak of each scan line) are kept only inside the
outline of a target board facing the camera (the whole printed board, margins included, its
edges projected through the camera's distortion); their rays meet that board's plane in 3-D
points of the light plane, and :func:`scanrig.reconstruct.light_plane_fit.fit_light_plane` fits the
plane to the points of all poses. Light on the floor, the turntable or the wall never enters the
fit, and a pose whose stripe is not on the target is named and left out. Given calibrations drawn
from the calibration's covariance, the same pixels are turned into points with each, and the
spread of the refitted planes joins the plane's uncertainty.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scanrig.errors import FileFormatError, InputError
from scanrig.io.session import read_image
from scanrig.laser.colour_check import colour_advice, colour_shown, one_colour
from scanrig.reconstruct.light_plane import intersect_plane, plane_from, with_sampled_uncertainty
from scanrig.reconstruct.light_plane_fit import LightPlaneFit, fit_light_plane

#: A pose with fewer stripe points on the target than this has no usable stripe.
MIN_POSE_POINTS = 20
#: Samples per board edge of the projected outline (the edges bend under lens distortion).
OUTLINE_SAMPLES = 32
#: A laser-off image whose median is this much above its laser-on image's was shot brighter, DN.
BRIGHTER_DARK_DN = 2.0


@dataclass(frozen=True)
class LightPlanePose:
    """One laser-on image of the target and what is known about its pose.

    Attributes
    ----------
    name : str
        The image's stem.
    image_path : Path
        The laser-on image.
    dark_path : Path or None
        The laser-off image of the same pose (subtracted before the stripe detection).
    world_from_target : RigidTransform
        The target's pose, world frame of the calibrated camera.
    """

    name: str
    image_path: Path
    dark_path: Path | None
    world_from_target: object


def board_outlines(camera, target, world_from_target) -> list:
    """Outlines in the image of the target's boards that face the camera.

    Parameters
    ----------
    camera : Camera
    target : Target
        Boards with ``target_from_board`` and ``size_m`` (printed area, margins included).
    world_from_target : RigidTransform

    Returns
    -------
    list of (int, ndarray of shape (4 * OUTLINE_SAMPLES, 2))
        Per facing board: its index in ``target.boards`` and its outline polygon, pixels.
    """
    s = np.linspace(0.0, 1.0, OUTLINE_SAMPLES, endpoint=False)[:, None]
    out = []
    for k, board in enumerate(target.boards):
        world_from_board = world_from_target @ board.target_from_board
        # board z points into the board: it faces the camera when the camera is on its -z side
        if (camera.center_world - world_from_board.t) @ world_from_board.R[:, 2] >= 0:
            continue
        w, h = board.size_m
        corners = np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h], [0.0, 0.0]])
        edge = np.concatenate([a + s * (b - a) for a, b in zip(corners[:-1], corners[1:])])
        polygon = camera.project(world_from_board.apply(np.c_[edge, np.zeros(len(edge))]))
        if np.all(np.isfinite(polygon)):
            out.append((k, polygon))
    return out


def inside_polygon(q: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Even-odd test of pixels ``(N, 2)`` against a closed polygon ``(M, 2)``; ``(N,)`` bool."""
    a, b = polygon, np.roll(polygon, -1, axis=0)
    u, v = q[:, :1], q[:, 1:]
    crosses = (a[:, 1] > v) != (b[:, 1] > v)
    with np.errstate(divide="ignore", invalid="ignore"):
        u_cross = a[:, 0] + (v - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    return (np.count_nonzero(crosses & (u < u_cross), axis=1) % 2) == 1


def stripe_pixels(camera, target, world_from_target, image: np.ndarray, dark: np.ndarray | None,
                  color: str) -> tuple[np.ndarray, np.ndarray]:
    """The laser stripe's centres on the target at one pose.

    The brightest stripe centre of every scan line within the outlines' bounding box
    (:func:`scanrig.detect_stripe`), kept where it falls inside a facing board's outline.

    Returns
    -------
    q : ndarray of shape (n, 2)
        Pixels.
    board : ndarray of shape (n,), int
        Index of the board (in ``target.boards``) each lies on.
    """
    q, board, _ = _stripe_on_target(camera, target, world_from_target, image, dark, color)
    return q, board


def _stripe_on_target(camera, target, world_from_target, image: np.ndarray, dark: np.ndarray | None, color: str,
                      saturation_level: str | None = "auto") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`stripe_pixels` ``q (n, 2)``, ``board (n,)`` and the fitted peak of each centre, ``(n,)`` DN,
    each channel clipped at its level found from the image (``saturation_level="auto"``, see
    :func:`scanrig.detect_stripe`) or at the dtype's maximum (None)."""
    from scanrig.laser.stripes import detect_stripe

    none = np.zeros((0, 2)), np.zeros(0, int), np.zeros(0)
    outlines = board_outlines(camera, target, world_from_target)
    if not outlines:
        return none
    corners = np.concatenate([polygon for _, polygon in outlines])
    u0, v0 = np.maximum(np.floor(corners.min(axis=0)).astype(int), 0)
    u1, v1 = np.minimum(np.ceil(corners.max(axis=0)).astype(int) + 1, [image.shape[1], image.shape[0]])
    if u1 - u0 < 2 or v1 - v0 < 2:
        return none
    # A wrong colour is named by the caller (_colour_hint), with the pose: not by every detection.
    table = detect_stripe(image, color=color, dark=dark, roi=(int(u0), int(v0), int(u1), int(v1)), check_color=False,
                          saturation_level=saturation_level)
    first = np.asarray(table.column("rank")) == 0
    q = np.column_stack([np.asarray(table.column("u")), np.asarray(table.column("v"))])[first]
    peak = np.asarray(table.column("peak"))[first]
    board = np.full(len(q), -1)
    for k, polygon in outlines:
        board[(board < 0) & inside_polygon(q, polygon)] = k
    on = board >= 0
    return q[on], board[on], peak[on]


def points_on_target(camera, target, world_from_target, q: np.ndarray, board: np.ndarray) -> np.ndarray:
    """Rays of pixels ``(n, 2)`` met with the planes of their boards: ``(n, 3)`` world points,
    metres (NaN where a ray misses its board's plane)."""
    centers, dirs = camera.rays(q)
    p = np.full((len(q), 3), np.nan)
    for k in np.unique(board):
        world_from_board = world_from_target @ target.boards[k].target_from_board
        normal = world_from_board.R[:, 2]
        on = board == k
        p[on] = intersect_plane(centers[on], dirs[on], plane_from(normal, normal @ world_from_board.t))[0]
    return p


def calibrate_light_plane_images(camera, target, poses: list[LightPlanePose], color: str,
                                 rng: np.random.Generator, samples=()) -> tuple[LightPlaneFit, list[str]]:
    """The light plane of one camera's laser from its laser-on images of the target.

    Parameters
    ----------
    camera : Camera
        Calibrated.
    target : Target
    poses : list of LightPlanePose
        Images whose target pose is known.
    color : {"grey", "red", "green", "blue"}
        Laser colour.
    rng : numpy.random.Generator
        For the robust fit.
    samples : sequence of (Camera, dict), optional
        Calibrations drawn from the calibration's covariance: the camera, and ``name ->
        world_from_target`` of the poses whose pose the calibration solved (the others keep
        theirs). The plane's uncertainty then includes the calibration's
        (:func:`scanrig.reconstruct.light_plane.with_sampled_uncertainty`).

    Returns
    -------
    fit : LightPlaneFit
    skipped : list of str
        One line per image left out (no stripe on the target).

    Raises
    ------
    InputError
        An image of the wrong size, no stripe on the target in any image (with the colour the
        images do show, when another colour finds it), another colour finding far more laser
        light on the target than ``color`` (in the pose with the most stripe points), fewer than 2
        usable poses (with the images left out and why), all poses in one plane, fewer than 2
        poses on one plane.

    Notes
    -----
    A laser-off twin brighter than its laser-on image was shot at another exposure (the target's
    own shot, as turntable scanners take it): it gives the pose but is not subtracted, and a
    warning says so.
    """
    used, points, skipped, first, notes = [], [], [], None, []
    for pose in poses:
        image, dark, note = _pose_frames(pose, camera)
        notes += [note] if note else []
        first = first or (pose, image, dark)
        q, board, _ = _stripe_on_target(camera, target, pose.world_from_target, image, dark, color)
        p = points_on_target(camera, target, pose.world_from_target, q, board)
        ok = np.all(np.isfinite(p), axis=1)
        if ok.sum() < MIN_POSE_POINTS:
            skipped.append(f"{pose.image_path}: no laser stripe on the target ({int(ok.sum())} points), skipped")
        else:
            used.append((pose, q[ok], board[ok]))
            points.append(p[ok])
    folder = poses[0].image_path.parent if poses else Path("light_plane") / camera.name
    if not points:
        hint = "" if first is None else _colour_hint(camera, target, color, *first)
        raise InputError(f"{folder}: no laser stripe found on the target in any of {len(poses)} image(s) with "
                         f"laser colour {color!r}{hint}")
    # the pose with the most stripe points: a wrong colour still finds junk on every pose
    pose, _, _ = max(used, key=lambda entry: len(entry[1]))
    if color != "grey":
        hint = _colour_hint(camera, target, color, pose, *_pose_frames(pose, camera)[:2])
        if hint:
            raise InputError(f"{folder}: {pose.image_path.name} shows little {color} laser light on the target{hint}")
    else:
        notes += _grey_note(camera, target, pose, *_pose_frames(pose, camera)[:2])
    if len(points) < 2:
        raise InputError("; ".join([f"{folder}: the stripe on the target was found in {len(points)} usable pose(s); "
                                    f"at least 2 are needed (6 or more at different distances and tilts)",
                                    *skipped, *notes]))
    fit = fit_light_plane(points, rng, [pose.name for pose, *_ in used])
    fit = dataclasses.replace(fit, warnings=fit.warnings + tuple(notes))
    p_samples = []
    for sample_camera, sample_poses in samples:
        p = np.concatenate([points_on_target(sample_camera, target, sample_poses.get(pose.name, pose.world_from_target),
                                             q, board) for pose, q, board in used])[fit.inliers]
        if np.all(np.isfinite(p)):
            p_samples.append(p)
    return dataclasses.replace(fit, plane=with_sampled_uncertainty(fit.plane, p_samples)), skipped


def _pose_frames(pose: LightPlanePose, camera) -> tuple[np.ndarray, np.ndarray | None, str | None]:
    """A pose's laser-on image, the laser-off twin to subtract (None: none, or one shot brighter, at
    another exposure: its median more than ``BRIGHTER_DARK_DN`` above the image's) and the warning
    for such a twin (else None)."""
    image = _read_sized(pose.image_path, camera)
    if pose.dark_path is None:
        return image, None, None
    dark = _read_sized(pose.dark_path, camera)
    if dark.shape != image.shape:
        raise FileFormatError(pose.dark_path, f"laser-off image is {dark.shape} but its laser-on image "
                                              f"{pose.image_path.name} is {image.shape}")
    dark_median, median = float(np.median(dark)), float(np.median(image))
    if dark_median <= median + BRIGHTER_DARK_DN:
        return image, dark, None
    return image, None, (f"{pose.dark_path}: brighter than its laser-on image {pose.image_path.name} (median "
                         f"{dark_median:.0f} against {median:.0f} DN), another exposure: used for the target's pose "
                         f"only, not subtracted (shoot a laser-off twin at the laser-on exposure)")


def _read_sized(path: Path, camera) -> np.ndarray:
    """An image that must have the camera's size."""
    image = read_image(path)
    if (image.shape[1], image.shape[0]) != (camera.width, camera.height):
        raise FileFormatError(path, f"image is {image.shape[1]}x{image.shape[0]} but camera {camera.name!r} "
                                    f"is {camera.width}x{camera.height}")
    return image


def _light(peak: np.ndarray) -> float:
    """The laser light of one pose's stripe centres on the target, DN: their fitted peaks ``(n,)``
    summed (0 with fewer than ``MIN_POSE_POINTS``)."""
    return float(np.clip(peak, 0.0, None).sum()) if peak.size >= MIN_POSE_POINTS else 0.0


def _light_with(camera, target, pose: LightPlanePose, image: np.ndarray, dark):
    """``light(colour) -> float``: the laser light (:func:`_light`) that ``colour`` finds on the target
    in one pose's image, with every channel clipped at the dtype's maximum (see :func:`_colour_hint`)."""
    def light(colour: str) -> float:
        return _light(_stripe_on_target(camera, target, pose.world_from_target, image, dark, colour, None)[2])

    return light


def _grey_note(camera, target, pose: LightPlanePose, image: np.ndarray, dark) -> list[str]:
    """``["lp03.png: the stripe is red, detected as grey ...: use --color red ..."]`` when one colour
    finds far more of a colour image's laser light on the target than each other colour
    (:func:`~scanrig.laser.colour_check.one_colour`), else ``[]``.

    Detected as grey, on the image's luma, the stripe is fitted among the print's edges at full
    weight: on the real Ciclop board the right-hand laser's points scatter 16.7 mm about the
    maker's plane (robust sigma) as grey, 0.06 mm as red."""
    laser = one_colour(image, _light_with(camera, target, pose, image, dark))
    return [] if laser is None else [f"{pose.image_path.name}: the stripe is {laser}, detected as grey on the "
                                     f"image's luma: {colour_advice(laser)}"]


def _colour_hint(camera, target, color: str, pose: LightPlanePose, image: np.ndarray, dark) -> str:
    """``"; the images show a red stripe: use --color red ..."`` when another colour finds far more
    laser light on the target (:func:`~scanrig.laser.colour_check.colour_shown`) in one pose's
    image, else ``""``.

    The light is the fitted peaks of the stripe centres on the target summed (0 with fewer than
    ``MIN_POSE_POINTS`` centres), not their number: a wrong colour finds a centre on most scan lines
    too, in noise and print (the real Ciclop board with a red laser: 331 centres in green, 863 in
    blue, 611 in red), but not the laser's brightness. Every colour is detected with the channels
    clipped at the dtype's maximum: a clip level found lower caps the summed peaks of a clipped
    stripe in its colour only (on the real Ciclop board, whose red clips at 180 DN, red over blue
    would fall from 3.39 to 2.93 times).
    """
    best = colour_shown(image, color, _light_with(camera, target, pose, image, dark), least=np.finfo(float).tiny)
    return "" if best is None else f"; the images show a {best} stripe: {colour_advice(best)}"
