"""``scanrig demo --quick`` end to end: every stage runs, the summary's figures are the files' figures,
and the demo, ``scanrig evaluate`` and the report quote one accuracy."""

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

#: Quick run: 4 cube poses, 12 stripe sheets, fx ~2200 px at ~1 m (1 px ~ 0.45 mm across the line
#: of sight). A calibration from 4 poses leaves camera-pose errors of up to a few millimetres (its
#: summary's standard deviations), so 2 mm RMS against the truth is what a working pipeline stays
#: below; a wrong world frame, a mismatched camera or an unrejected reflection gives centimetres.
QUICK_RMS_BOUND_MM = 2.0
#: rig.toml stores the calibration RMS rounded to 6 decimals.
RMS_ROUNDING_PX = 1e-6
#: An upright sheet crosses the scene from the floor to the top of the parts: several hundred scan
#: lines in each camera (~250 points per sheet pass the 0.1 mm precision cut, seed 0). A sheet
#: fanned sideways, edge-on to the cameras, gave ~30; 100 per sheet is the floor of a sweep that works.
MIN_POINTS_PER_SHEET = 100


@pytest.fixture(scope="module")
def quick_demo(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo") / "run"
    return run_demo(out, seed=3, quick=True, workers=2)


#: The quick demo renders, detects and reconstructs 12 full-size stripe frames and filters 1500
#: points: 2-3 minutes on 2 idle cores, many more on a shared machine.
DEMO_TIMEOUT_S = 1800


@pytest.mark.slow
@pytest.mark.timeout(DEMO_TIMEOUT_S)
def test_no_stage_fails_and_figures_match_the_files(quick_demo):
    from scanrig.io.ply import read_ply
    from scanrig.io.rig_file import load_rig_info
    from scanrig.reconstruct.points import read_points

    summary = quick_demo
    assert [(s.name, s.status) for s in summary.stages if s.status != "ok"] == []
    out = summary.out
    assert summary.mode == "stripe"                                  # the default
    _, _, metadata = load_rig_info(out / "rig.toml")
    assert summary.calibration_rms_px == pytest.approx(metadata["rms_px"], abs=RMS_ROUNDING_PX)
    cloud, comments = read_points(out / "points.ply")
    assert summary.n_points == len(cloud) >= MIN_POINTS_PER_SHEET * QUICK_STRIPE_FRAMES
    assert "seed: 3" in comments
    assert summary.rms_error_mm < QUICK_RMS_BOUND_MM
    _, faces, _ = read_ply(out / "mesh.ply")
    assert faces is not None and len(faces) > 0
    assert (out / "inspection" / "inspection.json").is_file() and (out / "inspection" / "inspection.html").is_file()
    html = (out / "report.html").read_text()
    assert "demo stage: calibrate" in html and "demo seed" in html


@pytest.mark.slow
@pytest.mark.timeout(DEMO_TIMEOUT_S)
def test_demo_evaluate_and_report_quote_one_accuracy(quick_demo, capsys):
    """The demo's RMS before and after the filter are what `scanrig evaluate` prints, with or without --rig."""
    summary, out = quick_demo, quick_demo.out
    for extra in ([], ["--rig", str(out / "rig.toml")]):
        assert main(["evaluate", str(out), "--histogram", str(out.parent / "h.png"), *extra]) == 0
        printed = capsys.readouterr().out
        assert f"{summary.n_points} points: RMS {summary.rms_error_mm:.4f} mm" in printed
        # The quick run filters a random 1500 of its points, and says so.
        assert re.search(rf"after the filter: \d+ kept, {summary.n_filter_removed} removed"
                         rf" \(the filter's input: {QUICK_FILTER_MAX_POINTS} of the {summary.n_points} points, "
                         rf"drawn at random\): RMS {summary.surface_rms_error_mm:.4f} mm", printed)
    verdict = (out / "report.html").read_text().split('<section id="summary">')[0]
    assert f"RMS {summary.rms_error_mm:.4f} mm: the RMS of the distances of all {summary.n_points} points" in verdict
    assert f"RMS {summary.surface_rms_error_mm:.4f} mm over the" in verdict


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
