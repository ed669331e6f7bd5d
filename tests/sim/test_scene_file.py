"""Scene files: the library loads, bad files fail naming the file and the field."""

from __future__ import annotations

import re

import numpy as np
import pytest
import trimesh

from scanrig.errors import FileFormatError, InputError
from scanrig.sim import load_scene, scene_names
from scanrig.sim.scene_file import load_scene_file

GOOD = """
name = "t"
[materials.paint]
kind = "matte"
[[objects]]
name = "ball"
shape = "sphere"
radius_m = 0.05
material = "paint"
"""


def _write(tmp_path, text, name="scene.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.parametrize("name", ["default", "plane", "sphere", "steps", "ibeam", "freeform"])
def test_library_scenes_load(name):
    scene = load_scene(name)
    assert scene.name == name
    for obj in scene.objects:
        assert len(obj.mesh.faces) > 0 and np.all(np.isfinite(obj.mesh.vertices))


def test_default_scene_is_half_metre_with_matte_and_shiny_parts():
    scene = load_scene("default")
    kinds = {o.material.kind for o in scene.objects}
    assert {"matte", "dark", "metal"} <= kinds
    parts = [o.mesh for o in scene.objects if o.name != "floor"]
    extent = np.ptp(np.vstack([m.vertices for m in parts]), axis=0)
    assert 0.35 < extent.max() < 0.65


def test_good_file_and_mesh_object(tmp_path):
    trimesh.creation.box(extents=(100.0, 50.0, 20.0)).export(tmp_path / "part.stl")
    text = GOOD + '\n[[objects]]\nname = "part"\nshape = "mesh"\nfile = "part.stl"\nscale = 0.001\nmaterial = "paint"\n'
    scene = load_scene_file(_write(tmp_path, text))
    part = scene.objects[1].mesh
    assert np.allclose(np.ptp(part.vertices, axis=0), [0.1, 0.05, 0.02])


@pytest.mark.parametrize("edit, message", [
    (lambda t: t + "\n[laser]\npowr = 1.0\n", "[laser]: unknown field 'powr' (did you mean 'power_W'?)"),
    (lambda t: t.replace('material = "paint"', 'material = "gold"'),
     "[[objects]] #1 ('ball'): material 'gold' is not defined; defined: ['paint']"),
    (lambda t: t.replace('shape = "sphere"', 'shape = "cone"'), "[[objects]] #1 ('ball'): shape must be one of"),
    (lambda t: t.replace("radius_m = 0.05", "radius_m = -0.05"),
     "[[objects]] #1 ('ball'): sphere radius_m must be 1 positive number(s), got [-0.05]"),
    (lambda t: t.replace("radius_m = 0.05", "radius = 0.05"),
     "[[objects]] #1 ('ball'): unknown field 'radius' (did you mean 'radius_m'?)"),
    (lambda t: t.replace("radius_m = 0.05", ""), "[[objects]] #1 ('ball'): missing field 'radius_m'"),
    (lambda t: t + "\n[sensor]\nbit_depth = 10\n", "[sensor]: sensor bit_depth must be 8, 12 or 16, got 10"),
    (lambda t: t.replace('kind = "matte"', 'kind = "matte"\nspecular = 0.5'),
     "[materials.paint]: material 'paint': specular must be 0 for kind 'matte'"),
    (lambda t: t.replace("[[objects]]", "[[object]]"), "top level: unknown field 'object' (did you mean 'objects'?)"),
    (lambda t: t + "\n[rig]\ndist = [0.1, 0.2]\n", "[rig]: rig dist must hold 5 coefficients"),
    (lambda t: t + "\n[[objects]]\nname = 'm'\nshape = 'mesh'\nfile = 'none.stl'\nmaterial = 'paint'\n",
     "none.stl: mesh file not found"),
    (lambda t: t + "\nname = 'again'\n", "not valid TOML"),
])
def test_bad_scene_file_names_file_and_field(tmp_path, edit, message):
    path = _write(tmp_path, edit(GOOD))
    with pytest.raises(FileFormatError, match=re.escape(message)) as info:
        load_scene_file(path)
    assert str(path.parent) in str(info.value)


def test_unknown_scene_name():
    with pytest.raises(InputError, match=re.escape(f"unknown scene 'castle'; built-in scenes are {scene_names()}")):
        load_scene("castle")
