"""Surveyed points for re-localising a camera: what a total station and an image would give.

A user whose camera moved measures a few scene points in world coordinates (total station, CMM
arm, or known fiducials) and marks them in the moved camera's image; ``scanrig relocate`` then
re-estimates that camera's pose alone. The simulator writes the same file for each camera,
``survey/<camera>.csv`` with columns ``point,x,y,z,u,v``, so that the workflow can be tried and
tested on a simulated session.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from scanrig.geometry import Rig
from scanrig.io.atomic import write_text_atomic
from scanrig.sim.scene import Scene

#: Grid of image positions (per side) whose lines of sight pick the surveyed points.
GRID_SIDE = 4
#: Share of the image width and height the grid spans, centred.
GRID_SPAN = 0.6
#: Noise of the surveyed world coordinates (total station, metres) and of the marked pixels.
SURVEY_SIGMA_M = 2e-5
MARK_SIGMA_PX = 0.1


def survey_points(scene: Scene, rig: Rig, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Scene points seen by each camera, with noisy world coordinates and pixel marks.

    Parameters
    ----------
    scene : Scene
    rig : Rig
        The true cameras.
    rng : numpy.random.Generator
        Source of the survey and marking noise.

    Returns
    -------
    dict
        Camera name -> array of shape (N, 5): x, y, z (world metres) and u, v (pixels), one row
        per grid line of sight that hits the scene (N <= ``GRID_SIDE ** 2``).
    """
    steps = (np.arange(GRID_SIDE) + 0.5) / GRID_SIDE - 0.5
    surveys = {}
    for cam in rig.cameras:
        u = cam.width / 2 + GRID_SPAN * cam.width * steps
        v = cam.height / 2 + GRID_SPAN * cam.height * steps
        uv = np.stack(np.meshgrid(u, v), axis=-1).reshape(-1, 2)
        origins, dirs = cam.rays(uv)
        hits = scene.raycaster.cast(origins, dirs)
        p_world = hits.point[hits.hit]
        uv_true = cam.project(p_world)
        rows = np.hstack([p_world + rng.normal(0.0, SURVEY_SIGMA_M, p_world.shape),
                          uv_true + rng.normal(0.0, MARK_SIGMA_PX, uv_true.shape)])
        surveys[cam.name] = rows
    return surveys


def write_survey(out: str | Path, scene: Scene, rig: Rig, rng: np.random.Generator) -> list[Path]:
    """Write ``survey/<camera>.csv`` for every camera (see :func:`survey_points`).

    Returns
    -------
    list of Path
        The files written.
    """
    folder = Path(out) / "survey"
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for name, rows in survey_points(scene, rig, rng).items():
        lines = ["point,x,y,z,u,v"] + [f"p{i},{','.join(repr(float(x)) for x in row)}" for i, row in enumerate(rows)]
        path = folder / f"{name}.csv"
        write_text_atomic(path, "\n".join(lines) + "\n")
        written.append(path)
    return written
