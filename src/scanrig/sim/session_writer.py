"""Simulate a whole session folder (DESIGN.md §4) with its ground truth under ``truth/``.

Written files::

    session.toml                          camera order, laser mode, target, seed
    scan/<camera>/<frame>.png             one laser frame per beam pose
    scan/<camera>/dark.png                the laser-off frame
    target.toml, calibration/<camera>/<shot>.png   (with_calibration)
                                          (colour cameras: RGB, .jpg when they store JPEG)
    light_plane/<camera>/lp<NN>.png       laser-on target shots of the first camera (light_plane_shots),
                                          laser-off twins in calibration/, true sheet in truth/light_plane.toml
    truth/rig.toml                        the true cameras (same format as a calibration result)
    truth/meshes/<object>.ply             object meshes in world coordinates, metres
    truth/frames.csv                      frame, kind, x, y, z: primary and secondary hits
    truth/laser.csv                       beam origin, direction and fan axis of every frame
    truth/target_poses.csv                world_from_target of every calibration shot
    truth/scene.toml                      copy of the scene file
    survey/<camera>.csv                   surveyed points (world x,y,z and pixels) for relocate

Frames and calibration shots are rendered in worker processes (fork); each has its own random
generator spawned from ``rng``, so the files do not depend on the number of workers.
"""

from __future__ import annotations

import io
from collections.abc import Callable
from pathlib import Path

import numpy as np

from scanrig.errors import InputError
from scanrig.geometry import Rig
from scanrig.io.atomic import write_bytes_atomic, write_text_atomic
from scanrig.io.ply import write_ply
from scanrig.io.rig_file import save_rig
from scanrig.parallel import run_indexed
from scanrig.sim.colour import write_frame
from scanrig.sim.laser import BeamPose, raster_poses, trace_laser
from scanrig.sim.library import load_scene, scene_path
from scanrig.sim.render import CameraView
from scanrig.sim.rigs import default_rig
from scanrig.sim.scene import Scene
from scanrig.sim.survey import write_survey

#: Progress callback: (stage, done, total).
Progress = Callable[[str, int, int], None]


def simulate_session(
    out: str | Path,
    scene: Scene | str = "default",
    n_cameras: int = 3,
    mode: str = "spot",
    n_frames: int = 100,
    rng: np.random.Generator | None = None,
    with_calibration: bool = True,
    n_shots: int = 12,
    target_kind: str = "cube",
    light_plane_shots: int = 0,
    rig: Rig | None = None,
    workers: int | None = None,
    progress: Progress | None = None,
    provenance: dict | None = None,
) -> Path:
    """Render a complete simulated session.

    Parameters
    ----------
    out : str or Path
        Session folder to create (may exist; files are overwritten).
    scene : Scene or str
        A scene, a built-in scene name or a scene file path.
    n_cameras : int
        Cameras of the default rig (ignored when ``rig`` is given).
    mode : {"spot", "stripe"}
    n_frames : int
        Laser frames (a pan/tilt raster covering the scene's region of interest).
    rng : numpy.random.Generator
        Source of all randomness (noise, target poses).
    with_calibration : bool
        Also write ``target.toml`` and ``calibration/`` images of the target in ``n_shots`` poses.
    n_shots : int
    target_kind : {"cube", "chessboard", "charuco"}
    light_plane_shots : int
        Poses of the (planar) target across a fixed line laser beside the first camera, for
        ``scanrig calibrate --light-plane`` (:mod:`scanrig.sim.light_plane_shots`); 0 for none.
    rig : Rig, optional
        Cameras to use instead of the scene's default rig.
    workers : int, optional
        Processes rendering frames (default: the number of CPUs, at most 4).
    progress : callable, optional
        Called as ``progress(stage, done, total)``.
    provenance : dict, optional
        Recorded in ``session.toml`` and ``truth/rig.toml`` (e.g. the seed and command line).

    Returns
    -------
    Path
        The session folder.
    """
    if rng is None:
        raise InputError("simulate_session needs rng (a numpy.random.Generator)")
    if mode not in ("spot", "stripe"):
        raise InputError(f"mode must be 'spot' or 'stripe', got {mode!r}")
    if with_calibration:
        from scanrig.sim.calibration_shots import default_target

        default_target(target_kind)  # an unknown target fails now, not after rendering the scan
    if light_plane_shots and target_kind == "cube":
        raise InputError("light-plane shots need a planar target: use target_kind 'chessboard' or 'charuco'")
    scene, scene_source = scene_and_source(scene)
    rig = rig or default_rig(n_cameras, scene.center_m, scene.rig)
    out = session_folder(out)
    progress = progress or (lambda stage, done, total: None)
    provenance = dict(provenance or {})
    bank_rngs, frame_rngs, dark_rng, calib_rng, survey_rng, light_rng = _spawn(rng, len(rig), n_frames)

    truth = out / "truth"
    for folder in [truth / "meshes"] + [out / "scan" / name for name in rig.names]:
        folder.mkdir(parents=True, exist_ok=True)

    views = [CameraView(cam, scene, rng=bank_rng) for cam, bank_rng in zip(rig.cameras, bank_rngs)]

    def render_background(i: int):
        return views[i].ray_table.xy, views[i].background_e

    # backgrounds in parallel, then kept by the parent's views (and inherited by frame workers)
    results = run_indexed(render_background, len(views), workers, lambda done: progress("background", done, len(rig)))
    for view, (xy, background) in zip(views, results):
        view.ray_table.__dict__["xy"] = xy
        view.__dict__["background_e"] = background
        view.noise  # noqa: B018 - draw the noise bank now, before forking
    for view in views:
        write_frame(out / "scan" / view.camera.name / "dark", view.sensor_frame(None, dark_rng), view.colour)

    poses = raster_poses(scene.laser, scene.center_m, scene.radius_m, n_frames, mode)
    stems = [f"{i:05d}" for i in range(len(poses))]
    truth_rows = _render_frames(out, scene, views, poses, stems, frame_rngs, workers, progress)

    _write_truth(out, scene, rig, poses, stems, truth_rows, scene_source, provenance)
    write_survey(out, scene, rig, survey_rng)
    if with_calibration:
        from scanrig.sim.calibration_shots import write_calibration

        write_calibration(out, scene, rig, n_shots, target_kind, calib_rng, workers, progress)
    if light_plane_shots:
        from scanrig.sim.calibration_shots import default_target
        from scanrig.sim.light_plane_shots import write_light_plane_shots
        from scanrig.targets import save_target

        target = default_target(target_kind)
        save_target(target, out / "target.toml")
        write_light_plane_shots(out, scene, rig, target, light_plane_shots, light_rng, workers=workers,
                                progress=progress)
    settings = {"cameras": rig.names, "laser_mode": mode, "laser_color": "red", "created_by": "scanrig simulate"}
    write_session_toml(out, "simulated session", settings, provenance,
                       with_target=bool(with_calibration or light_plane_shots))
    return out


def scene_and_source(scene: Scene | str) -> tuple[Scene, Path | None]:
    """The scene to render and the file it was read from.

    Parameters
    ----------
    scene : Scene or str
        A scene, a built-in scene name or a scene file path (ending in ``.toml``).

    Returns
    -------
    scene : Scene
    source : Path or None
        The scene file, copied to ``truth/scene.toml`` (:func:`write_truth_tables`); None for a
        ``Scene`` given as such.
    """
    if isinstance(scene, Scene):
        return scene, None
    source = Path(scene) if str(scene).endswith(".toml") else scene_path(str(scene))
    return load_scene(scene), source


def session_folder(out: str | Path) -> Path:
    """``out`` as the folder of a session to write (it may exist, as a folder).

    Raises
    ------
    InputError
        Where ``out`` is an existing file.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: output session folder is an existing file")
    return out


def write_session_toml(out: Path, what: str, settings: dict, provenance: dict, with_target: bool) -> None:
    """Write ``out/session.toml`` of a simulated session.

    Parameters
    ----------
    out : Path
        Session folder.
    what : str
        What was simulated, for the file's first comment line.
    settings : dict
        ``cameras``, ``laser_mode``, ``laser_color`` and ``created_by``; the ``seed`` of
        ``provenance`` (if any) follows, then ``target = "target.toml"`` when ``with_target``.
    provenance : dict
        The simulation's provenance (only its ``seed`` is written here).
    with_target : bool
        Whether the session holds ``target.toml``.
    """
    import tomli_w

    settings = {**settings, **{k: v for k, v in provenance.items() if k == "seed"}}
    if with_target:
        settings["target"] = "target.toml"
    write_text_atomic(out / "session.toml", f"# {what}; ground truth in truth/\n" + tomli_w.dumps(settings))


def _spawn(rng: np.random.Generator, n_cams: int, n_frames: int):
    banks = rng.spawn(n_cams)
    frames = rng.spawn(n_frames)
    dark, calib, survey, light = rng.spawn(4)   # children are keyed by index: adding one keeps the others
    return banks, frames, dark, calib, survey, light


def _render_frames(out, scene, views, poses, stems, frame_rngs, workers, progress) -> list:
    """Render and write every frame; returns ``(kinds, points)`` truth of each frame, in order."""

    def render_one(i: int):
        trace = trace_laser(poses[i], scene.laser, scene)
        for view in views:
            write_frame(out / "scan" / view.camera.name / stems[i], view.sensor_frame(trace, frame_rngs[i]),
                        view.colour)
        return trace.truth_kind, trace.truth_points

    return run_indexed(render_one, len(poses), workers, lambda done: progress("frames", done, len(poses)))


def _write_truth(out, scene, rig, poses, stems, truth_rows, scene_source, provenance) -> None:
    truth = out / "truth"
    save_rig(rig, truth / "rig.toml", metadata={"source": "scanrig simulate (true cameras)", **provenance},
             comments=["ground truth of a simulated session: the cameras that rendered the images"])
    write_truth_meshes(truth, scene)
    write_truth_tables(truth, stems, truth_rows, poses, scene_source)


def write_truth_tables(truth: Path, stems: list[str], truth_rows: list, poses: list[BeamPose],
                       scene_source: Path | None) -> None:
    """Write ``truth/frames.csv`` (:func:`frames_csv`), ``truth/laser.csv`` (:func:`laser_csv`)
    and, where the scene came from a file, its copy ``truth/scene.toml``.

    Parameters
    ----------
    truth : Path
        The session's ``truth`` folder.
    stems : list of str
        Frame stems, one per frame.
    truth_rows : list
        ``(kinds, points)`` of each frame: true hit kinds and points (world metres).
    poses : list of BeamPose
        The laser of each frame (world frame, metres).
    scene_source : Path or None
        The scene file (:func:`scene_and_source`).
    """
    write_text_atomic(truth / "frames.csv", frames_csv(stems, truth_rows))
    write_text_atomic(truth / "laser.csv", laser_csv(poses, stems))
    if scene_source is not None:
        write_bytes_atomic(truth / "scene.toml", Path(scene_source).read_bytes())


def write_truth_meshes(truth: Path, scene: Scene, frame: str = "world frame") -> None:
    """Write ``truth/meshes/<object>.ply`` of every object of ``scene`` (vertices in ``frame``, metres)."""
    for obj in scene.objects:
        v = obj.mesh.vertices
        write_ply(truth / "meshes" / f"{obj.name}.ply", {"x": v[:, 0], "y": v[:, 1], "z": v[:, 2]}, obj.mesh.faces,
                  comments=[f"scanrig simulate: object {obj.name!r}, material {obj.material.name!r}",
                            f"{frame}, metres (float64)"])


def frames_csv(stems: list[str], truth_rows: list) -> str:
    """Text of ``truth/frames.csv``: the ``(kinds, points)`` hits of each frame, world metres."""
    lines = ["frame,kind,x,y,z"]
    for stem, (kinds, points) in zip(stems, truth_rows):
        lines += [f"{stem},{k},{p[0]!r},{p[1]!r},{p[2]!r}" for k, p in zip(kinds, points.tolist())]
    return "\n".join(lines) + "\n"


def laser_csv(poses: list[BeamPose], stems: list[str]) -> str:
    """Text of ``truth/laser.csv``: one row per frame, world metres (fan axis empty for spots)."""
    buf = io.StringIO()
    buf.write("frame,origin_x,origin_y,origin_z,dir_x,dir_y,dir_z,fan_x,fan_y,fan_z\n")
    for stem, pose in zip(stems, poses):
        fan = ["", "", ""] if pose.fan_axis is None else [repr(float(v)) for v in pose.fan_axis]
        vals = [repr(float(v)) for v in (*pose.origin, *pose.direction)] + fan
        buf.write(",".join([stem, *vals]) + "\n")
    return buf.getvalue()
