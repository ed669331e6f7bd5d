"""``scanrig demo --quick`` end to end, as its ``--help`` example runs it: every stage runs, the
summary's figures are the files' figures, and the demo, ``scanrig evaluate`` and the report quote
one accuracy. The run is the test session's shared one (``tests/quick_demo.py``)."""

import re

import pytest

from scanrig.cli.main import main
from scanrig.demo import (
    QUICK_FILTER_MAX_POINTS,
    QUICK_STRIPE_FRAMES,
    DemoSettings,
    run_demo,
)
from scanrig.errors import InputError
from tests.quick_demo import DEMO_TIMEOUT_S

#: Quick run: 4 cube poses, 12 stripe sheets, fx ~2200 px at ~1 m (1 px ~ 0.45 mm across the line
#: of sight). A calibration from 4 poses leaves camera-pose errors of up to a few millimetres (its
#: summary's standard deviations), so 2 mm RMS against the truth is what a working pipeline stays
#: below; a wrong world frame, a mismatched camera or an unrejected reflection gives centimetres.
QUICK_RMS_BOUND_MM = 2.0
#: An upright sheet crosses the scene from the floor to the top of the parts: several hundred scan
#: lines in each camera (3126 points from the 12 sheets pass the 0.1 mm precision cut, seed 1). A
#: sheet fanned sideways, edge-on to the cameras, gave ~30; 100 per sheet is the floor of a sweep
#: that works.
MIN_POINTS_PER_SHEET = 100
#: rig.toml stores the calibration RMS rounded to 6 decimals; the summary prints it to 4.
RMS_ROUNDING_PX, PRINTED_RMS_ROUNDING_PX = 0.5e-6, 0.5e-4
#: The demo's stages, in the order its table lists them.
STAGES = ("simulate calibration", "calibrate", "scan", "detect", "reconstruct", "filter", "evaluate", "inspect",
          "report")


def _figure(rows: dict[str, list[str]], name: str, unit: str) -> str:
    """The number of the summary's figure ``name``, as printed (its ``unit`` removed)."""
    value = rows[name][0]
    assert value.endswith(unit), f"{name}: {value!r} is not in {unit!r}"
    return value.removesuffix(unit).strip()


@pytest.fixture(scope="module")
def demo_run(quick_demo):
    quick_demo.example.check()
    return quick_demo.example


@pytest.mark.slow
@pytest.mark.timeout(DEMO_TIMEOUT_S)
def test_no_stage_fails_and_figures_match_the_files(demo_run):
    from scanrig.io.ply import read_ply
    from scanrig.io.rig_file import load_rig_info
    from scanrig.reconstruct.points import read_points

    rows, out = demo_run.table_rows(), demo_run.out
    assert [(stage, rows[stage][0]) for stage in STAGES if rows[stage][0] != "ok"] == []
    mode, seed = rows["mode, seed"][0].split(", ")
    assert mode == "stripe" and f"--seed {seed}" in demo_run.command   # stripe is the default
    _, _, metadata = load_rig_info(out / "rig.toml")
    assert float(_figure(rows, "calibration RMS reprojection error", "px")) == pytest.approx(
        metadata["rms_px"], abs=PRINTED_RMS_ROUNDING_PX + RMS_ROUNDING_PX)
    cloud, comments = read_points(out / "points.ply")
    assert int(rows["points (points.ply)"][0]) == len(cloud) >= MIN_POINTS_PER_SHEET * QUICK_STRIPE_FRAMES
    assert f"seed: {seed}" in comments
    assert float(_figure(rows, "RMS distance to the truth, all points", "mm")) < QUICK_RMS_BOUND_MM
    _, faces, _ = read_ply(out / "mesh.ply")
    assert faces is not None and len(faces) > 0
    assert (out / "inspection" / "inspection.json").is_file() and (out / "inspection" / "inspection.html").is_file()
    html = (out / "report.html").read_text()
    assert "demo stage: calibrate" in html and "demo seed" in html


@pytest.mark.slow
@pytest.mark.timeout(DEMO_TIMEOUT_S)
def test_demo_evaluate_and_report_quote_one_accuracy(demo_run, tmp_path, capsys):
    """The demo's RMS before and after the filter are what `scanrig evaluate` prints, with or without --rig."""
    rows, out = demo_run.table_rows(), demo_run.out
    n_points = rows["points (points.ply)"][0]
    rms_mm = _figure(rows, "RMS distance to the truth, all points", "mm")
    surface_rms_mm = _figure(rows, "RMS distance to the truth, points the filter kept", "mm")
    n_removed = rows["points the filter removed"][0]
    for extra in ([], ["--rig", str(out / "rig.toml")]):
        assert main(["evaluate", str(out), "--histogram", str(tmp_path / "h.png"), *extra]) == 0
        printed = capsys.readouterr().out
        assert f"{n_points} points: RMS {rms_mm} mm" in printed
        # The quick run filters a random 1500 of its points, and says so.
        assert re.search(rf"after the filter: \d+ kept, {n_removed} removed"
                         rf" \(the filter's input: {QUICK_FILTER_MAX_POINTS} of the {n_points} points, "
                         rf"drawn at random\): RMS {surface_rms_mm} mm", printed)
    verdict = (out / "report.html").read_text().split('<section id="summary">')[0]
    assert f"RMS {rms_mm} mm: the RMS of the distances of all {n_points} points" in verdict
    assert f"RMS {surface_rms_mm} mm over the" in verdict


def test_summary_tables_are_read_cell_by_cell(tmp_path, capsys, monkeypatch):
    """The demo's printed tables, as the shared run's tests read them (``DemoRun.table_rows``)."""
    from scanrig.demo import DemoSummary, StageRecord
    from tests.quick_demo import WIDE_COLUMNS, DemoRun

    summary = DemoSummary(tmp_path / "demo", "stripe", 1, DemoSettings(), [
        StageRecord("calibrate", "ok", 9.1, "RMS 0.008 px, 951 target points"),
        StageRecord("filter", "failed: EstimationError", 61.5, "too few points to fit a surface: 3 (at least 20)")],
        calibration_rms_px=0.0084, n_points=3012, rms_error_mm=0.0621, wall_s=215.7)
    monkeypatch.setattr("scanrig.demo.run_demo", lambda out, **kwargs: summary)
    monkeypatch.setenv("COLUMNS", str(WIDE_COLUMNS))
    assert main(["demo", "--out", str(tmp_path / "demo")]) == 1
    rows = DemoRun("scanrig demo", tmp_path / "demo", 1, capsys.readouterr().out).table_rows()
    assert rows["calibrate"] == ["ok", "9.1", "RMS 0.008 px, 951 target points"]
    assert rows["filter"][0] == "failed: EstimationError"
    assert rows["points (points.ply)"] == ["3012"] and rows["mode, seed"] == ["stripe, 1"]
    assert _figure(rows, "RMS distance to the truth, all points", "mm") == "0.0621"
    assert rows["points the filter removed"] == ["not reached"]


def test_settings_and_bad_input(tmp_path, capsys):
    assert DemoSettings.preset(quick=True, frames=7).budget == 7
    assert DemoSettings.preset(quick=True).budget == QUICK_STRIPE_FRAMES
    assert DemoSettings.preset(quick=True, mode="spot").budget == 80
    with pytest.raises(InputError, match="mode must be one of"):
        run_demo(tmp_path / "x", mode="sheet")
    with pytest.raises(InputError, match="frames must be a positive integer, got 0"):
        DemoSettings.preset(quick=False, frames=0)
    (tmp_path / "used" / "scan").mkdir(parents=True)
    with pytest.raises(InputError, match=re.escape(f"{tmp_path / 'used'} already holds a scan")):
        run_demo(tmp_path / "used")
    assert main(["demo", "--out", str(tmp_path / "used")]) == 2
    err = capsys.readouterr().err
    assert f"{tmp_path / 'used'} is not empty (it holds scan/) and scanrig demo would overwrite" in err
