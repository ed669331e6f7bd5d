"""``scanrig relocate`` rewrites rig.toml only when it reports that the camera moved, or with --force."""

import numpy as np
import pytest

import scanrig
from scanrig.calibration.synthetic import ring_cameras
from scanrig.cli.main import main
from tests.calibration.test_relocate import points_in_view

#: Pixel noise on the known points: the unmoved camera's pose change stays within 3 sigma.
SIGMA_PX = 0.1


@pytest.fixture
def unmoved(tmp_path):
    """A two-camera rig.toml and twelve known points seen by cam1 where the rig says it is."""
    rng = np.random.default_rng(8)
    rig = scanrig.Rig(ring_cameras(2))
    scanrig.save_rig(rig, tmp_path / "rig.toml")
    cam = rig.cameras[1]
    p_world = points_in_view(cam, 12, rng)
    uv = cam.project(p_world) + rng.normal(scale=SIGMA_PX, size=(12, 2))
    rows = [f"p{k},{x!r},{y!r},{z!r},{u!r},{v!r}"
            for k, ((x, y, z), (u, v)) in enumerate(zip(p_world.tolist(), uv.tolist()))]
    (tmp_path / "known.csv").write_text("\n".join(["point,x,y,z,u,v", *rows]) + "\n")
    return tmp_path, cam.name


def test_relocate_leaves_the_rig_when_the_camera_did_not_move(unmoved, capsys):
    root, name = unmoved
    before = (root / "rig.toml").read_bytes()
    assert main(["relocate", str(root), "--camera", name, "--points", str(root / "known.csv"),
                 "--sigma-px", str(SIGMA_PX)]) == 0
    out = capsys.readouterr().out
    assert "camera moved: no (change within 3 sigma)" in out
    assert f"{root / 'rig.toml'} left unchanged (--force updates it anyway)" in out
    assert "updated" not in out
    assert (root / "rig.toml").read_bytes() == before


def test_relocate_force_updates_the_rig_and_says_so(unmoved, capsys):
    root, name = unmoved
    before = (root / "rig.toml").read_bytes()
    assert main(["relocate", str(root), "--camera", name, "--points", str(root / "known.csv"),
                 "--sigma-px", str(SIGMA_PX), "--force"]) == 0
    out = capsys.readouterr().out
    assert "camera moved: no" in out
    assert f"updated {root / 'rig.toml'} (--force: the change is not significant)" in out
    assert (root / "rig.toml").read_bytes() != before
    assert f"relocated_{name}" in (root / "rig.toml").read_text()
