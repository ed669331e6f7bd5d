"""``calibration_report/summary.json``: its keys and types, and agreement with rig.toml and summary.txt."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from scanrig.calibration.pipeline import REPORT_DIR, calibrate
from scanrig.calibration.session_calibration import write_session_outputs
from scanrig.calibration.summary import SUMMARY_FORMAT_VERSION, dropped_view_warnings
from scanrig.calibration.synthetic import DETECTABLE_SQUARE_PX, ring_cameras, simulate
from scanrig.io.rig_file import load_rig_info
from scanrig.targets import cube

TARGET = cube()
#: Detections moved by this much are gross errors (200 sigma of the 0.1 px noise): all rejected.
GROSS_ERROR_PX = 20.0
#: Which detections get a gross error: every 97th, so both cameras get some.
GROSS_EVERY = 97

TOP_KEYS = {"format_version": int, "target_kind": str, "n_shots": int, "world_frame": str, "rms_px": float,
            "sigma_px": float, "n_observations": int, "n_outliers": int, "cross_validation_reference_camera": str,
            "cameras": list, "warnings": list}
CAMERA_KEYS = {"name": str, "model": str, "width": int, "height": int, "param_names": list, "params": list,
               "params_std": list, "rms_px": float, "n_observations": int, "n_outliers": int, "n_views": int,
               "center_std_m": list, "rotation_std_deg": float, "poorly_determined": list,
               "projection_sigma_px": dict, "cross_validation": dict, "camera_agreement": dict}
CROSS_VALIDATION_KEYS = {"measured_px": float, "predicted_px": float, "ratio": float, "dof": int,
                         "max_px": float, "n_points": int, "splits": dict}
AGREEMENT_KEYS = {"rms_alone_px": float, "rms_rig_px": float, "ratio": float, "dof": float, "p_value": float}


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """A calibrated two-camera session with some gross errors, written to a folder."""
    rng = np.random.default_rng(5)
    sim = simulate(ring_cameras(2, rng=rng), TARGET, 8, 0.1, rng, cover=True, min_square_px=DETECTABLE_SQUARE_PX)
    gross = np.arange(len(sim.obs)) % GROSS_EVERY == 0
    obs = dataclasses.replace(sim.obs, uv=sim.obs.uv + GROSS_ERROR_PX * gross[:, None])
    result = calibrate(obs, TARGET, "opencv5")
    root = tmp_path_factory.mktemp("session")
    write_session_outputs(root, result, obs, plots=False, command_line="scanrig calibrate session")
    return root, result, obs, gross


def _check_types(record: dict, spec: dict, where: str) -> None:
    assert set(record) == set(spec), where
    for key, kind in spec.items():
        assert isinstance(record[key], kind) and not isinstance(record[key], bool), f"{where}.{key}"


@pytest.mark.slow
def test_summary_json_keys_and_types(written):
    root, result, _, _ = written
    summary = json.loads((root / REPORT_DIR / "summary.json").read_text(encoding="utf-8"))
    _check_types(summary, TOP_KEYS, "summary")
    assert summary["format_version"] == SUMMARY_FORMAT_VERSION
    for cam in summary["cameras"]:
        _check_types(cam, CAMERA_KEYS, cam["name"])
        _check_types(cam["cross_validation"], CROSS_VALIDATION_KEYS, f"{cam['name']}.cross_validation")
        _check_types(cam["camera_agreement"], AGREEMENT_KEYS, f"{cam['name']}.camera_agreement")
        assert cam["camera_agreement"]["ratio"] == result.camera_agreement[cam["name"]].ratio
        assert set(cam["projection_sigma_px"]) == {"depth_m", "median", "max"}
        assert len(cam["params"]) == len(cam["params_std"]) == len(cam["param_names"])
        assert all(isinstance(v, float) for v in cam["params"] + cam["params_std"] + cam["center_std_m"])
        for entry in cam["poorly_determined"]:
            assert set(entry) == {"param", "std", "moved_px"}
        check = result.cross_validation.cameras[cam["name"]]
        assert cam["cross_validation"]["measured_px"] == check.measured_px
        assert cam["cross_validation"]["predicted_px"] == check.predicted_px


@pytest.mark.slow
def test_summary_json_agrees_with_rig_toml_and_counts(written):
    root, result, obs, gross = written
    summary = json.loads((root / REPORT_DIR / "summary.json").read_text(encoding="utf-8"))
    rig, info, metadata = load_rig_info(root / "rig.toml")
    assert [c["name"] for c in summary["cameras"]] == rig.names
    for cam in summary["cameras"]:
        solved = rig[cam["name"]]
        assert (cam["model"], cam["width"], cam["height"]) == (solved.model, solved.width, solved.height)
        assert cam["param_names"] == list(solved.param_names)
        assert cam["params"] == [float(v) for v in solved.params]
        assert cam["params_std"] == info[cam["name"]]["params_std"]
        assert cam["n_observations"] == info[cam["name"]]["n_observations"]
        assert cam["rms_px"] == pytest.approx(info[cam["name"]]["rms_px"], abs=1e-6)   # rig.toml rounds to 1e-6
        injected = int(np.count_nonzero(gross & (obs.camera == obs.camera_names.index(cam["name"]))))
        assert cam["n_outliers"] == injected
    assert sum(c["n_outliers"] for c in summary["cameras"]) == summary["n_outliers"] == metadata["n_outliers"]
    assert sum(c["n_observations"] for c in summary["cameras"]) == summary["n_observations"]
    assert summary["n_observations"] + summary["n_outliers"] == len(obs)
    assert summary["world_frame"] == metadata["world_frame"]


@pytest.mark.slow
def test_summary_json_warnings_are_the_printed_lines(written):
    root, result, _, _ = written
    summary = json.loads((root / REPORT_DIR / "summary.json").read_text(encoding="utf-8"))
    text = (root / REPORT_DIR / "summary.txt").read_text(encoding="utf-8")
    printed = [line.removeprefix("WARNING: ") for line in text.splitlines() if line.startswith("WARNING: ")]
    assert summary["warnings"] == printed == result.warnings
    assert all("\n" not in w for w in summary["warnings"])


@pytest.mark.slow
def test_summary_json_without_cross_validation(tmp_path, written):
    _, _, obs, _ = written
    result = calibrate(obs, TARGET, "opencv5", cross_validate=False)
    write_session_outputs(tmp_path, result, obs, plots=False)
    summary = json.loads((tmp_path / REPORT_DIR / "summary.json").read_text(encoding="utf-8"))
    assert summary["cross_validation_reference_camera"] is None
    assert all(cam["cross_validation"] is None and cam["camera_agreement"] is None for cam in summary["cameras"])


def test_dropped_views_give_one_line_per_camera():
    dropped = [("cam2", f"{s}", "PnP failed") for s in range(35, 42)] + [("cam3", "75", "3 points < 4")]
    lines = dropped_view_warnings(dropped)
    assert lines == ["cam2: 7 view(s) left out of the initialisation: 35 (PnP failed), 36 (PnP failed), "
                     "37 (PnP failed) and 4 more",
                     "cam3: 1 view(s) left out of the initialisation: 75 (3 points < 4)"]
