"""``scanrig scan``, ``design`` and ``report`` into a log: plain progress lines with counts; the
design's camera table whole at 80 columns."""

import csv
import re
from pathlib import Path

import numpy as np
import pytest
import trimesh

from scanrig.cli.main import main

SCAN_SCENE = str(Path(__file__).parents[1] / "scan" / "data" / "small_sphere.toml")
DONE_LINE = r"{}: done, {} in \d+\.\d s"


@pytest.mark.slow
def test_scan_into_a_log_prints_each_pass_with_counts(tmp_path, capsys):
    """stdout is not a terminal under pytest: each pass's frames are grabbed, then processed, each
    stage with a start and an end line (counts of the pass's beams)."""
    argv = ["scan", str(tmp_path / "s"), "--sim", SCAN_SCENE, "--sim-scale", "0.25", "--spacing-mm", "12",
            "--roi-mm=-70,-70,5,70,70,130", "--workers", "1", "--budget", "40", "--seed", "3"]
    assert main(argv) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0] == "preparing (dark frame, first beams): started"
    assert re.fullmatch(r"preparing \(dark frame, first beams\): done in \d+\.\d s", out[1])
    n_frames, n_passes = map(int, re.match(r"(\d+) frames in (\d+) passes", out[-1]).groups())
    assert n_frames == 40 and n_passes >= 2
    grabbed = 0
    for k in range(1, n_passes + 1):
        started = next(line for line in out if line.startswith(f"pass {k}: grabbing frames: started"))
        n_beams = int(re.fullmatch(rf"pass {k}: grabbing frames: started, (\d+) to do", started).group(1))
        assert any(re.fullmatch(DONE_LINE.format(f"pass {k}: grabbing frames", f"{n_beams}/{n_beams}"), line)
                   for line in out)
        assert f"pass {k}: processing frames: started" in out
        assert any(re.fullmatch(rf"pass {k}: processing frames: done in \d+\.\d s", line) for line in out)
        grabbed += n_beams
    assert grabbed == n_frames


@pytest.fixture()
def part_mesh(tmp_path):
    mesh = trimesh.creation.box((0.1, 0.08, 0.06))
    mesh.apply_translation([0.0, 0.0, 0.03])
    mesh.export(tmp_path / "part.stl")
    spec = tmp_path / "spec.toml"
    spec.write_text('[mounting]\nn_candidates = 16\n[target]\nsigma_m = 3e-4\n')
    return tmp_path / "part.stl", spec


@pytest.mark.slow
def test_design_into_a_log_prints_stages_and_a_whole_table_at_80_columns(part_mesh, tmp_path, capsys,
                                                                         monkeypatch):
    monkeypatch.setenv("COLUMNS", "80")
    mesh, spec = part_mesh
    out_dir = tmp_path / "design"
    assert main(["design", "--mesh", str(mesh), "--cameras", "3", "--spec", str(spec), "--out", str(out_dir)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "rating candidate cameras: started, 16 to do"
    assert re.fullmatch(DONE_LINE.format("rating candidate cameras", "16/16"), lines[1])
    assert lines[2] == "writing outputs: started"
    assert re.fullmatch(r"writing outputs: done in \d+\.\d s", lines[3])
    assert max(len(line) for line in lines) <= 80 and not any("…" in line for line in lines)
    # every camera's row shows its numbers whole: the position in mm as cameras.csv gives it in m
    with open(out_dir / "cameras.csv", newline="") as f:
        cameras = list(csv.DictReader(f))
    rows = {line.split()[0]: line.split() for line in lines if re.match(r"\s*cam\d+ ", line)}
    assert sorted(rows) == [c["camera"] for c in cameras]
    for camera in cameras:
        shown_mm = np.array(rows[camera["camera"]][2:5], dtype=float)
        true_mm = 1e3 * np.array([float(camera[k]) for k in ("x_m", "y_m", "z_m")])
        np.testing.assert_allclose(shown_mm, true_mm, atol=0.5)   # rounded to whole millimetres


def test_camera_table_of_a_far_rig_fits_80_columns():
    """The widest numbers a rig gives (10 m away, 100 %, two-digit camera names) stay whole."""
    import io

    from rich.console import Console

    from scanrig.cli.design import camera_table

    row = {"focal_length_mm": 12.5, "x_m": -9.412, "y_m": -9.803, "z_m": -9.401, "distance_m": 9.999,
           "seen_fraction": 1.0, "in_focus_fraction": 1.0, "covered_after": 1.0, "marginal_gain": 1.0,
           "loss_if_removed": 1.0}
    screen = io.StringIO()
    Console(file=screen, width=80).print(camera_table([{"camera": f"cam{i}", **row} for i in (1, 10)], "title"))
    lines = screen.getvalue().splitlines()
    assert max(len(line) for line in lines) <= 80 and not any("…" in line for line in lines)
    assert lines[-2].split() == ["cam10", "12.5", "-9412", "-9803", "-9401", "9999", "100.0", "100", "100.0",
                                 "100.0", "100.0"]


@pytest.mark.slow
def test_analysing_a_rig_into_a_log_prints_its_stage(part_mesh, tmp_path, capsys):
    mesh, spec = part_mesh
    assert main(["design", "--mesh", str(mesh), "--cameras", "3", "--spec", str(spec),
                 "--out", str(tmp_path / "d")]) == 0
    capsys.readouterr()
    assert main(["design", "--mesh", str(mesh), "--rig", str(tmp_path / "d" / "rig.toml"),
                 "--out", str(tmp_path / "check")]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "analysing the rig: started, 1 to do"
    assert re.fullmatch(DONE_LINE.format("analysing the rig", "1/1"), lines[1])


def test_report_into_a_log_prints_each_section(tmp_path, capsys):
    """An empty session still gets a report (it says what is missing); every section has its lines."""
    session = tmp_path / "s"
    session.mkdir()
    assert main(["report", str(session)]) == 0
    lines = capsys.readouterr().out.splitlines()
    started = [line.removesuffix(": started") for line in lines if line.endswith(": started")]
    assert started[0] == "report: calibration" and len(started) >= 4
    for section in started:
        assert any(re.fullmatch(rf"{section}: done in \d+\.\d s", line) for line in lines)
    assert lines[-1] == f"wrote {session / 'report.html'}"


def test_demo_tables_whole_at_80_columns(tmp_path, capsys, monkeypatch):
    """The demo's two tables with its longest stage results, in an 80-column terminal."""
    from scanrig.demo import DemoSettings, DemoSummary, StageRecord

    summary = DemoSummary(tmp_path / "demo", "stripe", 0, DemoSettings(), [
        StageRecord("simulate calibration", "ok", 39.4, "4 cube poses x 3 cameras (1280x1024 px)"),
        StageRecord("calibrate", "ok", 122.7, "RMS 0.017 px, 951 target points"),
        StageRecord("reconstruct", "ok", 1.7, "123456 points from 80 frames; 8 candidates rejected"),
        StageRecord("filter", "failed: EstimationError", 61.5, "too few points to fit a surface: 3 (at least 20)")],
        calibration_rms_px=0.0171, n_points=123456, n_rejected=8, rms_error_mm=0.016, surface_rms_error_mm=None,
        wall_s=215.7)
    monkeypatch.setattr("scanrig.demo.run_demo", lambda out, **kwargs: summary)
    monkeypatch.setenv("COLUMNS", "80")
    assert main(["demo", "--out", str(tmp_path / "demo")]) == 1
    lines = capsys.readouterr().out.splitlines()
    assert max(len(line) for line in lines) <= 80 and not any("…" in line for line in lines)
    text = "\n".join(lines)
    for _, value in summary.figures():   # every figure whole
        assert value in text
    assert "122.7" in text
