"""load_cad: STL, PLY and OBJ in metres or millimetres, several bodies merged."""

import numpy as np
import pytest
import trimesh

from scanrig.inspect import load_cad

from . import synth


@pytest.mark.parametrize("suffix", [".stl", ".ply", ".obj"])
def test_a_millimetre_file_is_read_in_metres(tmp_path, suffix):
    mesh = synth.bracket_mesh()
    mm = mesh.copy()
    mm.apply_scale(1000.0)
    path = tmp_path / f"part{suffix}"
    mm.export(path)
    cad = load_cad(path, units="mm")
    # 1e-9 m: the files store float32 or decimal text of millimetre coordinates
    np.testing.assert_allclose(cad.bounds, mesh.bounds, atol=1e-9)
    assert cad.is_watertight and cad.volume == pytest.approx(mesh.volume, rel=1e-6)


def test_several_bodies_become_one_mesh(tmp_path):
    a = trimesh.creation.box(extents=(0.01, 0.01, 0.01))
    b = trimesh.creation.box(extents=(0.01, 0.01, 0.01))
    b.apply_translation((0.05, 0.0, 0.0))
    path = tmp_path / "two.obj"
    trimesh.Scene([a, b]).export(path)
    cad = load_cad(path)
    assert len(cad.faces) == len(a.faces) + len(b.faces)
    np.testing.assert_allclose(cad.bounds, [[-0.005, -0.005, -0.005], [0.055, 0.005, 0.005]], atol=1e-9)
