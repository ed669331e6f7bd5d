"""Calibration shots: printed targets (cube, chessboard, ChArUco) in random poses, rendered.

Each board of a :class:`scanrig.targets.Target` becomes a flat rectangle whose albedo is the
board's own printed reflectance function (black ink on white paper), sampled exactly at every
ray hit; edges are pixel-integrated by the renderer's sub-pixel supersampling. The cube's six
boards form its closed surface. Poses are random but keep the target in view of at least two
cameras (a pose may cut the target at the image border in some cameras). A scene's
``board_flex_m`` bends every board (:func:`scanrig.targets.target.flex_shape`): the rectangle
becomes a grid of triangles whose chords stay within ``primitives.MAX_SAG_M`` of the bent
surface, printed at the same board (x, y).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from scanrig.errors import EstimationError, InputError
from scanrig.geometry import Rig, RigidTransform
from scanrig.io.atomic import write_text_atomic
from scanrig.sim import primitives
from scanrig.sim.colour import still_frame, write_frame
from scanrig.sim.materials import Material
from scanrig.sim.pixel_rays import PixelRayTable
from scanrig.sim.render import CameraView
from scanrig.sim.scene import Scene, SceneObject

#: Reflectance of paper and ink.
PAPER_ALBEDO = 0.85
INK_ALBEDO = 0.04
#: Fraction of the full well reached by white paper under the scene's room light.
PAPER_FILL = 0.7
#: Sub-pixel samples per axis at edges in calibration shots (corner accuracy): with 8, noise-free
#: rendered ChArUco corners lie within 0.005 px RMS of their true projections (with 4, 0.016 px:
#: more than the 0.007 px that the pixel noise gives them).
CALIBRATION_SUPERSAMPLING = 8
#: ``random_pose(cover_field=True)``: range of the target's distance from the camera, as
#: fractions of the camera's distance to the scene's ``center_m``.
COVER_RANGE = (0.35, 0.8)
#: Pose attempts before giving up.
_MAX_TRIES = 500


@dataclass(frozen=True)
class PrintedMaterial(Material):
    """Matte paper printed with a board's pattern."""

    board: object = None
    board_from_world: RigidTransform | None = None

    def albedo_at(self, p_world: np.ndarray) -> np.ndarray:
        xy = self.board_from_world.apply(p_world)[:, :2]
        return INK_ALBEDO + (PAPER_ALBEDO - INK_ALBEDO) * self.board.reflectance(xy)


def default_target(kind: str):
    """The target used by simulated sessions: ``cube`` (20 cm ChArUco cube), ``chessboard`` or ``charuco``."""
    from scanrig import targets

    makers = {"cube": lambda: targets.cube(edge_m=0.2),
              "chessboard": lambda: targets.chessboard(inner_corners=(9, 6), square_m=0.03),
              "charuco": lambda: targets.charuco(squares=(7, 5), square_m=0.04, marker_m=0.03)}
    if kind not in makers:
        raise InputError(f"target kind must be one of {sorted(makers)}, got {kind!r}")
    return makers[kind]()


def target_scene(target, world_from_target: RigidTransform, room: Scene) -> Scene:
    """A scene holding only the target at a pose, lit like ``room``, its boards bent by
    ``room.board_flex_m``."""
    objects = []
    flex_m = np.asarray(room.board_flex_m, dtype=np.float64)
    for board in target.boards:
        w, h = board.size_m
        world_from_board = world_from_target @ board.target_from_board
        if np.any(flex_m):
            rect = bent_board_mesh(board, flex_m)
            rect.apply_transform(world_from_board.as_matrix())
        else:
            rect = primitives.plane((w, h))
            m = world_from_board.as_matrix() @ np.array([[1, 0, 0, w / 2], [0, 1, 0, h / 2], [0, 0, 1, 0],
                                                         [0, 0, 0, 1.0]])
            rect.apply_transform(m)
        mat = PrintedMaterial(board.name, "matte", albedo=PAPER_ALBEDO, board=board,
                              board_from_world=world_from_board.inverse())
        objects.append(SceneObject(board.name, rect, mat))
    return replace(room, name=f"{room.name}+target", objects=tuple(objects))


def bent_board_mesh(board, flex_m: np.ndarray):
    """A board's printed rectangle bent by ``flex_m``, in the board frame.

    Parameters
    ----------
    board : scanrig.targets.Board
    flex_m : ndarray of shape (2,)
        ``(c_x, c_y)`` of :func:`scanrig.targets.target.flex_shape`, metres.

    Returns
    -------
    trimesh.Trimesh
        A regular grid over ``[0, w] x [0, h]`` at ``z = flex_shape(x, y) · flex_m``, split into
        triangles oriented as :func:`scanrig.sim.primitives.plane`'s; along each axis the chord of a cell
        departs from the parabola by at most ``primitives.MAX_SAG_M / 2``.
    """
    import trimesh

    from scanrig.targets.target import flex_shape

    size = np.asarray(board.size_m, dtype=np.float64)
    grid = board.points_local
    half = 0.5 * (grid.max(axis=0) - grid.min(axis=0))
    # Chord sag of z = c (x / half)² over a cell of width d is c d² / (4 half²).
    cells = np.maximum(1, np.ceil(size / half * np.sqrt(np.abs(flex_m) / (2.0 * primitives.MAX_SAG_M)))).astype(int)
    xx, yy = np.meshgrid(np.linspace(0.0, size[0], cells[0] + 1), np.linspace(0.0, size[1], cells[1] + 1))
    xy = np.column_stack([xx.ravel(), yy.ravel()])
    vertices = np.column_stack([xy, flex_shape(board, xy) @ flex_m])
    corner = (np.arange(cells[1])[:, None] * (cells[0] + 1) + np.arange(cells[0])[None, :]).ravel()
    right, up = corner + 1, corner + cells[0] + 1
    faces = np.concatenate([np.column_stack([corner, right, up + 1]), np.column_stack([corner, up + 1, up])])
    return trimesh.Trimesh(vertices, faces, process=False)


def calibration_sensor(room: Scene):
    """The scene's sensor with an exposure that puts white paper at PAPER_FILL of the full well."""
    s = room.sensor
    light = room.lighting
    radiance = PAPER_ALBEDO * (light.ambient_W_m2 + light.lamp_W_m2) / np.pi
    exposure = s.exposure_s * PAPER_FILL * s.full_well_e / (radiance * s.e_per_radiance)
    return replace(s.with_exposure(exposure), supersampling=max(s.supersampling, CALIBRATION_SUPERSAMPLING))


def random_pose(target, rig: Rig, center_m, radius_m: float, rng: np.random.Generator,
                cover_field: bool = False) -> RigidTransform:
    """A random ``world_from_target`` whose points are seen (in front, in the image) by >= 2 cameras
    (by the camera, in a single-camera rig).

    ``cover_field``: the target's centre on the line of sight of a pixel drawn uniformly over the
    image of a randomly chosen camera, at :data:`COVER_RANGE` times the camera's distance to
    ``center_m``, facing that camera (a planar target tilted as below), so that shots reach the
    image corners of a wide-angle lens.

    Raises
    ------
    EstimationError
        If no such pose is found (cameras do not share a view of the region).
    """
    from scipy.spatial.transform import Rotation

    center = np.asarray(center_m, dtype=np.float64)
    centres = np.array([c.center_world for c in rig.cameras])
    towards_cams = centres.mean(axis=0) - center
    towards_cams /= np.linalg.norm(towards_cams)
    pts = target.points_target
    for _ in range(_MAX_TRIES):
        towards = towards_cams
        if cover_field:
            position, towards = _position_on_a_sight_line(rig, center, rng)
            if position is None:
                continue
        if target.is_planar:
            # board z (into the print) points away from the cameras, tilted up to 40 degrees
            z = -towards
            tilt = Rotation.from_rotvec(rng.normal(size=3) * np.radians(20))
            base = Rotation.align_vectors([z], [[0.0, 0.0, 1.0]])[0]
            R = (tilt * base * Rotation.from_rotvec([0, 0, rng.uniform(-np.pi, np.pi)])).as_matrix()
        else:
            R = Rotation.random(random_state=rng).as_matrix()
        if not cover_field:
            position = center + rng.uniform(-0.5, 0.5, size=3) * radius_m
        t = position - R @ pts.mean(axis=0)
        pose = RigidTransform(R, t)
        if _n_cameras_seeing(target, pose, rig) >= _min_cameras(rig):
            return pose
    raise EstimationError("could not place the calibration target in view of two cameras; "
                          "check that the cameras look at the scene's center_m")


def _position_on_a_sight_line(rig: Rig, center: np.ndarray, rng: np.random.Generator):
    """A point on the line of sight of a random pixel of a random camera (see :func:`random_pose`)
    and the unit direction from it to that camera; ``(None, None)`` where the pixel has no ray."""
    cam = rig.cameras[rng.integers(len(rig))]
    q = rng.uniform((0.0, 0.0), (cam.width - 1.0, cam.height - 1.0))
    xy, ok = cam.unproject(q[None, :])
    if not ok[0]:
        return None, None
    sight_world = cam.cam_from_world.R.T @ np.append(xy[0], 1.0)
    sight_world /= np.linalg.norm(sight_world)
    distance = rng.uniform(*COVER_RANGE) * np.linalg.norm(center - cam.center_world)
    return cam.center_world + distance * sight_world, -sight_world


def _min_cameras(rig: Rig) -> int:
    """Cameras that must see a calibration pose: two (they are tied together), or a lone camera."""
    return min(2, len(rig))


def _n_cameras_seeing(target, world_from_target: RigidTransform, rig: Rig) -> int:
    """Cameras that see at least half of the target points facing them inside the image."""
    n = 0
    for cam in rig.cameras:
        seen = 0
        for board in target.boards:
            world_from_board = world_from_target @ board.target_from_board
            p = world_from_board.apply(board.points_board)
            facing = (cam.center_world - world_from_board.t) @ world_from_board.R[:, 2] < 0
            if not facing:
                continue
            q = cam.project(p)
            inside = np.isfinite(q).all(1) & (q[:, 0] >= 0) & (q[:, 1] >= 0)
            inside &= (q[:, 0] <= cam.width - 1) & (q[:, 1] <= cam.height - 1)
            seen += int(inside.sum())
        n += seen >= 0.5 * len(target.boards[0].points_board)
    return n


def write_calibration(out: Path, room: Scene, rig: Rig, n_shots: int, target_kind: str,
                      rng: np.random.Generator, workers: int | None = None,
                      progress=None) -> dict[str, RigidTransform]:
    """Write ``target.toml``, ``calibration/<camera>/<shot>.png`` (``.jpg`` from a colour camera
    that stores JPEG), ``truth/target_poses.csv`` and, for a scene whose boards bend,
    ``truth/board_flex.csv``; returns ``world_from_target`` by shot stem.

    Poses are drawn from ``rng`` in order; each shot's noise has its own spawned generator.
    """
    from scanrig.parallel import run_indexed
    from scanrig.targets import save_target

    target = default_target(target_kind)
    save_target(target, out / "target.toml")
    sensor = calibration_sensor(room)
    poses = [random_pose(target, rig, room.center_m, room.radius_m, rng, room.rig.cover_field)
             for _ in range(n_shots)]
    if _n_cameras_seeing(target, RigidTransform.identity(), rig) >= _min_cameras(rig):
        # Shot 000 at the world origin: a calibration takes the target's frame at its first shot
        # as the world frame, so the calibrated rig then lives in the scene's own frame (as a
        # user defines the world by where the cube first stands) and its clouds, relocations
        # and evaluations need no alignment.
        poses[0] = RigidTransform.identity()
    shot_rngs = rng.spawn(n_shots)
    stems = [f"{i:03d}" for i in range(n_shots)]
    tables = [PixelRayTable(cam) for cam in rig.cameras]
    for table in tables:
        table.xy  # noqa: B018 - solve each camera's rays once, before forking
    for name in rig.names:
        (out / "calibration" / name).mkdir(parents=True, exist_ok=True)

    def render_shot(i: int) -> None:
        scene = target_scene(target, poses[i], room)
        for cam, table in zip(rig.cameras, tables):
            image = still_frame(CameraView(cam, scene, sensor, ray_table=table).background_e, sensor, room.colour,
                                shot_rngs[i])
            write_frame(out / "calibration" / cam.name / stems[i], image, room.colour)

    report = (lambda done: progress("calibration", done, n_shots)) if progress else None
    run_indexed(render_shot, n_shots, workers, report)
    lines = ["shot,r11,r12,r13,r21,r22,r23,r31,r32,r33,tx,ty,tz"]
    for stem, pose in zip(stems, poses):
        lines.append(",".join([stem, *(repr(float(v)) for v in pose.R.ravel()), *(repr(float(v)) for v in pose.t)]))
    write_text_atomic(out / "truth" / "target_poses.csv", "\n".join(lines) + "\n")
    if any(room.board_flex_m):
        write_text_atomic(out / "truth" / "board_flex.csv",
                          "c_x_m,c_y_m\n" + ",".join(repr(float(v)) for v in room.board_flex_m) + "\n")
    return dict(zip(stems, poses))
