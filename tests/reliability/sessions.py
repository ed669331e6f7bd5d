"""Small good sessions for the bad-input matrix: built in a second, without the simulator."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from scanrig.geometry import Camera, Rig, RigidTransform
from scanrig.io.rig_file import save_rig
from scanrig.io.session import write_image

WIDTH, HEIGHT = 64, 48
CAMERAS = ("cam0", "cam1")
FRAMES = ("f0", "f1")


def spot_image(u: int, v: int) -> np.ndarray:
    """A dark 8-bit frame (48, 64) with a 3x3 bright spot at column ``u``, row ``v``."""
    img = np.full((HEIGHT, WIDTH), 10, np.uint8)
    img[v - 1:v + 2, u - 1:u + 2] = 200
    return img


def small_rig() -> Rig:
    """Two pinhole cameras 64x48 looking down +z at the world origin from 1 m, 0.2 m apart."""
    cams = [Camera(name, "pinhole", [60.0, 60.0, 31.5, 23.5], WIDTH, HEIGHT,
                   RigidTransform.from_rvec_tvec([0.0, 0.1 * (-1) ** i, 0.0], [0.1 * (-1) ** (i + 1), 0.0, 1.0]))
            for i, name in enumerate(CAMERAS)]
    return Rig(cams)


def build_session(root: Path) -> Path:
    """scan/<cam>/<frame>.png, rig.toml, traces.parquet (from ``scanrig detect``), points.ply and
    truth/meshes/box.ply: every input of detect, reconstruct and evaluate, all valid."""
    import trimesh

    from scanrig.cli.main import main
    from scanrig.reconstruct.points import PointCloud, write_points

    for i, cam in enumerate(CAMERAS):
        (root / "scan" / cam).mkdir(parents=True)
        for j, stem in enumerate(FRAMES):
            write_image(root / "scan" / cam / f"{stem}.png", spot_image(30 + 2 * i + 3 * j, 20 + j))
    save_rig(small_rig(), root / "rig.toml")
    assert main(["detect", str(root), "--mode", "spot"]) == 0
    rng = np.random.default_rng(5)
    n = 20
    cloud = PointCloud(rng.uniform(-0.05, 0.05, (n, 3)), np.full(n, 1e-4), np.full(n, 2), np.zeros(n),
                       np.arange(n) % 2, np.zeros(n))
    write_points(root / "points.ply", cloud)
    (root / "truth" / "meshes").mkdir(parents=True)
    trimesh.creation.box(extents=(0.1, 0.1, 0.1)).export(root / "truth" / "meshes" / "box.ply")
    save_rig(small_rig(), root / "truth" / "rig.toml")
    return root
