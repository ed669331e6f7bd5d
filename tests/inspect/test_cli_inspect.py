"""``scanrig inspect`` end to end: files, JSON keys, exit codes and one-line errors."""

import json

import numpy as np
import pytest

from scanrig.cli.main import main
from scanrig.io.ply import read_ply, write_ply

from . import synth

#: Keys of inspection.json (DESIGN.md section 4, plus the alignment, regions and warnings).
JSON_KEYS = {"cad_from_cloud", "n_points", "rms_m", "mean_m", "p95_abs_m", "max_abs_m", "tolerance_m",
             "within_tolerance", "alignment", "regions", "warnings", "signed", "seed", "units", "title", "written_by"}
#: Deviation error allowed on the small CLI scan: the acceptance bound, 1.5 x the noise.
DEVIATION_TOL = 1.5 * synth.NOISE_M


def _write_cloud(path, points_m):
    write_ply(path, {"x": points_m[:, 0], "y": points_m[:, 1], "z": points_m[:, 2]})


@pytest.fixture(scope="module")
def part(tmp_path_factory):
    """A CAD file in millimetres and a scan of it (moved, partial, outliers)."""
    folder = tmp_path_factory.mktemp("part")
    mesh = synth.bracket_mesh()
    mm = mesh.copy()
    mm.apply_scale(1000.0)
    mm.export(folder / "bracket_mm.stl")
    scan = synth.scan_of(mesh, np.random.default_rng(21), 6000)
    _write_cloud(folder / "scan.ply", scan.points_m)
    return folder, scan


@pytest.mark.slow
def test_inspect_writes_ply_json_and_html(part, tmp_path, capsys):
    folder, scan = part
    out = tmp_path / "result"
    args = ["inspect", str(folder / "scan.ply"), "--cad", str(folder / "bracket_mm.stl"), "--cad-units", "mm",
            "--out", str(out), "--tolerance-mm", "0.1", "--seed", "3"]
    assert main(args) == 0
    assert "within ±0.1 mm" in capsys.readouterr().out
    summary = json.loads((out / "inspection.json").read_text())
    assert set(summary) == JSON_KEYS
    assert summary["n_points"] == len(scan.points_m) and summary["tolerance_m"] == pytest.approx(1e-4)
    assert np.array(summary["cad_from_cloud"]).shape == (4, 4)
    vertices, faces, comments = read_ply(out / "inspection.ply")
    assert comments[0].startswith("written by scanrig inspect: scanrig inspect ")
    assert list(vertices) == ["x", "y", "z", "deviation_m", "red", "green", "blue"]
    assert vertices["deviation_m"].dtype == np.float32 and faces is None
    assert synth.deviation_error_m(scan, vertices["deviation_m"].astype(float)) <= DEVIATION_TOL
    html = (out / "inspection.html").read_text()
    assert "Worst regions" in html and "<script" in html and "http://" not in html.split("</head>")[1]
    # a second run replaces its own files (without aligning again: quicker, and it still writes all three)
    assert main([*args, "--no-align"]) == 0
    assert json.loads((out / "inspection.json").read_text())["alignment"]["method"] == "none"


def test_foreign_files_are_never_overwritten(part, tmp_path, capsys):
    folder, _ = part
    out = tmp_path / "result"
    out.mkdir()
    (out / "inspection.json").write_text("{}")
    code = main(["inspect", str(folder / "scan.ply"), "--cad", str(folder / "bracket_mm.stl"), "--cad-units", "mm",
                 "--out", str(out)])
    assert code == 2
    assert capsys.readouterr().err.strip() == (f"error: {out / 'inspection.json'}: exists and was not written by "
                                               "scanrig inspect; give another --out folder (nothing was written)")
    assert sorted(p.name for p in out.iterdir()) == ["inspection.json"]


def _error(args, capsys):
    assert main(["inspect", *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    return err[0]


def test_bad_input_exits_2_with_one_line_and_writes_nothing(part, tmp_path, capsys):
    folder, _ = part
    out = tmp_path / "out"
    cad = ["--cad", str(folder / "bracket_mm.stl"), "--out", str(out)]
    empty = tmp_path / "empty.ply"
    _write_cloud(empty, np.zeros((0, 3)))
    assert _error([str(empty), *cad, "--cad-units", "mm"], capsys) == (
        f"error: {empty}: the cloud is empty (no vertices)")

    assert _error([str(folder / "scan.ply"), *cad], capsys).startswith(
        f"error: {folder / 'bracket_mm.stl'}: the CAD is ")
    line = _error([str(folder / "scan.ply"), *cad], capsys)
    assert line.endswith("looks like millimetres read as metres; give --cad-units mm")

    garbage = tmp_path / "garbage.stl"
    garbage.write_bytes(b"\x00\x01 not a mesh")
    assert _error([str(folder / "scan.ply"), "--cad", str(garbage), "--out", str(out)], capsys) == (
        f"error: {garbage}: not a readable mesh (no triangles found)")

    points_only = tmp_path / "points_only.ply"
    _write_cloud(points_only, np.random.default_rng(0).random((50, 3)))
    assert _error([str(folder / "scan.ply"), "--cad", str(points_only), "--out", str(out)], capsys) == (
        f"error: {points_only}: holds no triangles (a CAD model must be a triangle mesh, not points)")

    assert _error([str(folder / "scan.ply"), "--cad", str(tmp_path / "missing.stl"), "--out", str(out)], capsys) == (
        f"error: {tmp_path / 'missing.stl'}: no such file")

    assert _error([str(folder / "scan.ply"), *cad, "--cad-units", "inch"], capsys) == (
        "error: --cad-units must be one of m, mm, got 'inch'")

    assert _error([str(folder / "scan.ply"), *cad, "--cad-units", "mm", "--tolerance-mm", "0"], capsys) == (
        "error: --tolerance-mm must be > 0, got 0.0")

    initial = tmp_path / "initial.txt"
    initial.write_text("1 0 0\n0 1 0\n")
    assert _error([str(folder / "scan.ply"), *cad, "--cad-units", "mm", "--initial", str(initial)], capsys) == (
        f"error: {initial}: --initial: matrix must have shape (4, 4), got (2, 3)")

    session = tmp_path / "session"
    session.mkdir()
    assert _error([str(session), *cad, "--cad-units", "mm"], capsys) == (
        f"error: {session}: session folder holds no points.ply (scanrig reconstruct writes it)")
    assert not out.exists()


@pytest.mark.slow
def test_a_cloud_that_cannot_be_aligned_exits_2(part, tmp_path, capsys):
    folder, _ = part
    d = np.random.default_rng(1).normal(size=(3000, 3))
    sphere = tmp_path / "sphere.ply"
    _write_cloud(sphere, 0.03 * d / np.linalg.norm(d, axis=1, keepdims=True))
    line = _error([str(sphere), "--cad", str(folder / "bracket_mm.stl"), "--cad-units", "mm",
                   "--out", str(tmp_path / "out")], capsys)
    assert line.startswith(f"error: {sphere}: the cloud cannot be aligned to the CAD model: the best fit brings ")
    assert not (tmp_path / "out").exists()


def test_session_folder_uses_the_points_the_filter_kept(part, tmp_path, capsys):
    _, scan = part
    mesh = synth.bracket_mesh()
    p_cad = scan.points_m @ scan.cad_from_cloud[:3, :3].T + scan.cad_from_cloud[:3, 3]
    session = tmp_path / "session"
    session.mkdir()
    inlier = (~scan.outlier).astype(np.uint8)
    write_ply(session / "surface.ply", {"x": p_cad[:, 0], "y": p_cad[:, 1], "z": p_cad[:, 2], "inlier": inlier})
    mesh.export(tmp_path / "bracket.ply")
    out = tmp_path / "out"
    assert main(["inspect", str(session), "--cad", str(tmp_path / "bracket.ply"), "--out", str(out), "--no-align"]) == 0
    assert f"{int(inlier.sum())} points of {session / 'surface.ply'}" in capsys.readouterr().out
    summary = json.loads((out / "inspection.json").read_text())
    assert summary["n_points"] == int(inlier.sum())
    assert summary["alignment"] == {"method": "none", "residual_rms_m": None, "inlier_fraction": None, "iterations": 0,
                                    "constraint": None}
    json.loads((out / "inspection.json").read_text(), parse_constant=lambda c: pytest.fail(f"{c} is not JSON"))


def test_initial_transform_from_a_text_file(part, tmp_path, capsys):
    folder, scan = part
    initial = tmp_path / "initial.txt"
    np.savetxt(initial, scan.cad_from_cloud)
    out = tmp_path / "out"
    assert main(["inspect", str(folder / "scan.ply"), "--cad", str(folder / "bracket_mm.stl"), "--cad-units", "mm",
                 "--out", str(out), "--initial", str(initial)]) == 0
    summary = json.loads((out / "inspection.json").read_text())
    assert summary["alignment"]["method"] == "initial + robust ICP"
    vertices, _, _ = read_ply(out / "inspection.ply")
    assert synth.deviation_error_m(scan, vertices["deviation_m"].astype(float)) <= DEVIATION_TOL
