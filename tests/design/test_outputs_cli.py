"""Design outputs (rig file, maps, tables) and the ``scanrig design`` command."""

import csv
import io
import tomllib

import numpy as np
import pytest
import trimesh

from scanrig.cli.main import main
from scanrig.design import analyze_existing, design_rig
from scanrig.design.outputs import camera_table_csv, design_summary, vertex_maps, write_views_png
from scanrig.io.ply import read_ply
from scanrig.io.rig_file import load_rig, save_rig

from .scenes import small_spec


@pytest.fixture(scope="module")
def part():
    mesh = trimesh.creation.box((0.1, 0.08, 0.06))
    mesh.apply_translation([0.0, 0.0, 0.03])
    return mesh


@pytest.fixture(scope="module")
def design(part):
    return design_rig(part, 3, small_spec(), np.random.default_rng(4), search_elements=3000)


def test_vertex_maps_take_the_worst_face(design):
    mesh, a = design.mesh, design.analysis
    maps = vertex_maps(mesh, a)
    assert set(maps) == {"x", "y", "z", "n_views", "sigma", "speckle_floor", "triangulation_angle_deg",
                         "density_per_mm2", "covered"}
    v = int(mesh.faces[0, 0])
    around = np.flatnonzero((mesh.faces == v).any(axis=1))
    assert maps["n_views"][v] == a.n_views[around].min()
    worst = a.sigma_m[around].max()
    assert (np.isnan(maps["sigma"][v]) and np.isinf(worst)) or maps["sigma"][v] == worst
    assert maps["covered"][v] == int(a.covered[around].all())


def test_camera_table_and_summary(design):
    rows = list(csv.DictReader(io.StringIO(camera_table_csv(design))))
    assert [r["camera"] for r in rows] == ["cam0", "cam1", "cam2"]
    assert float(rows[0]["focal_length_mm"]) == pytest.approx(12.0)
    assert sum(float(r["marginal_gain"]) for r in rows) == pytest.approx(design.selection.covered_fraction, abs=1e-5)
    summary = design_summary(design)
    assert summary["covered_fraction"] == design.analysis.covered_fraction
    assert summary["ring_covered_fraction"] == design.ring.covered_fraction
    assert summary["covered_fraction"] <= summary["seen_by_min_views_fraction"] <= summary["seen_by_one_fraction"]


def test_views_png(design, tmp_path):
    path = tmp_path / "views.png"
    write_views_png(path, design, size_px=120)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_analysing_the_designed_rig_reproduces_its_prediction(design, part, tmp_path):
    save_rig(design.rig, tmp_path / "rig.toml")
    again = analyze_existing(part, load_rig(tmp_path / "rig.toml"), design.spec, search_elements=3000)
    np.testing.assert_array_equal(again.analysis.n_views, design.analysis.n_views)
    np.testing.assert_allclose(again.analysis.sigma_m, design.analysis.sigma_m, rtol=1e-12)


def test_cli_design_writes_a_rig_for_simulate(part, tmp_path):
    part.export(tmp_path / "part.stl")
    spec = tmp_path / "spec.toml"
    spec.write_text('[mounting]\nn_candidates = 16\n[target]\nsigma_m = 3e-4\n')
    out = tmp_path / "design"
    code = main(["design", "--mesh", str(tmp_path / "part.stl"), "--cameras", "3", "--spec", str(spec),
                 "--out", str(out), "--seed", "3"])
    assert code == 0
    rig = load_rig(out / "rig.toml")
    assert rig.names == ["cam0", "cam1", "cam2"]
    vertices, faces, comments = read_ply(out / "coverage.ply")
    assert faces is not None and len(vertices["sigma"]) == len(vertices["x"])
    summary = tomllib.loads((out / "design.toml").read_text())
    assert summary["provenance"]["seed"] == "3"
    assert summary["spec"]["target"]["sigma_m"] == 3e-4
    assert (out / "coverage.png").stat().st_size > 0 and (out / "cameras.csv").is_file()


@pytest.mark.parametrize("args, message", [
    (["--cameras", "3"], "give exactly one of --mesh FILE or --scene NAME"),
    (["--mesh", "missing.stl"], "missing.stl: not a readable mesh"),
    (["--scene", "nosuchscene"], "unknown scene 'nosuchscene'"),
])
def test_cli_bad_input_exits_2(tmp_path, capsys, args, message):
    assert main(["design", *args, "--out", str(tmp_path / "o")]) == 2
    assert message in capsys.readouterr().err


def test_cli_target_below_speckle_limit_exits_2_with_the_best_figure(part, tmp_path, capsys):
    part.export(tmp_path / "part.stl")
    spec = tmp_path / "spec.toml"
    spec.write_text("[target]\nsigma_m = 1e-8\n")
    code = main(["design", "--mesh", str(tmp_path / "part.stl"), "--spec", str(spec), "--out", str(tmp_path / "o")])
    assert code == 2
    err = capsys.readouterr().err
    assert "is below the speckle limit of these optics: the best achievable with 3 cameras is" in err
