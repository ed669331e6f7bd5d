"""``scanrig demo --quick`` end to end: every stage runs, the summary's figures are the files' figures."""

import re

import pytest

from scanrig.cli.main import main
from scanrig.demo import DemoSettings, run_demo
from scanrig.errors import InputError

#: Quick run: 4 cube poses, 80 beams, fx ~2200 px at ~1 m (1 px ~ 0.45 mm across the line of sight).
#: A calibration from 4 poses leaves camera-pose errors of up to a few millimetres (its summary's
#: standard deviations), so 2 mm RMS against the truth is what a working pipeline stays below; a
#: wrong world frame, a mismatched camera or an unrejected reflection gives centimetres.
QUICK_RMS_BOUND_MM = 2.0
#: rig.toml stores the calibration RMS rounded to 6 decimals.
RMS_ROUNDING_PX = 1e-6


@pytest.fixture(scope="module")
def quick_demo(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo") / "run"
    return run_demo(out, seed=3, quick=True, workers=2)


@pytest.mark.slow
def test_no_stage_fails_and_figures_match_the_files(quick_demo):
    from scanrig.io.rig_file import load_rig_info
    from scanrig.reconstruct.points import read_points

    summary = quick_demo
    failed = [(s.name, s.status) for s in summary.stages if s.status.startswith("failed")]
    assert failed == []
    out = summary.out
    _, _, metadata = load_rig_info(out / "rig.toml")
    assert summary.calibration_rms_px == pytest.approx(metadata["rms_px"], abs=RMS_ROUNDING_PX)
    cloud, comments = read_points(out / "points.ply")
    assert summary.n_points == len(cloud) > 0
    assert "seed: 3" in comments
    assert summary.rms_error_mm < QUICK_RMS_BOUND_MM
    html = (out / "report.html").read_text()
    assert "demo stage: calibrate" in html and "demo seed" in html


@pytest.mark.slow
def test_every_stage_is_available(quick_demo):
    missing = [(s.name, s.status) for s in quick_demo.stages if s.status != "ok"]
    assert missing == [], "stages that did not run in the quick demo"


def test_settings_and_bad_input(tmp_path, capsys):
    assert DemoSettings.preset(quick=True, frames=7).budget == 7
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
