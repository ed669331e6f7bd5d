"""``scanrig reconstruct --max-sigma-mm``: validated, and it leaves out the imprecise points in both modes."""

import numpy as np
import pytest

from scanrig.cli.main import main
from scanrig.io.rig_file import save_rig
from scanrig.laser.traces import write_traces
from scanrig.reconstruct.points import read_points
from tests.reconstruct.synth import points_in_cube, ring_rig, spot_traces, stripe_traces


@pytest.mark.parametrize("value", ["0", "-0.1", "inf", "nan"])
def test_bad_max_sigma_is_one_error_line(tmp_path, capsys, value):
    assert main(["reconstruct", str(tmp_path), f"--max-sigma-mm={value}"]) == 2
    captured = capsys.readouterr()
    assert captured.err.splitlines() == [f"error: --max-sigma-mm must be a finite number > 0, got {float(value)}"]


def _reconstruct(session, capsys, max_sigma_mm: str):
    out = session / f"points_{max_sigma_mm}.ply"
    assert main(["reconstruct", str(session), "--out", str(out), "--max-sigma-mm", max_sigma_mm]) == 0
    return read_points(out)[0], capsys.readouterr().out


@pytest.mark.parametrize("mode", ["stripe", "spot"])
def test_max_sigma_leaves_out_the_imprecise_points(tmp_path, capsys, mode):
    rng = np.random.default_rng(67)
    rig = ring_rig(height_m=0.6)
    save_rig(rig, tmp_path / "rig.toml")
    if mode == "stripe":
        table = stripe_traces(rig, [-0.03, 0.05], rng, 0.2)
    else:
        table, _ = spot_traces(rig, points_in_cube(rng, 40), rng, 0.3)
    write_traces(tmp_path / "traces.parquet", table, {})
    loose, _ = _reconstruct(tmp_path, capsys, "10")
    limit_mm = 1e3 * float(np.median(loose.sigma))
    tight, text = _reconstruct(tmp_path, capsys, f"{limit_mm}")
    precise = loose.sigma <= 1e-3 * limit_mm
    kept = np.isin(_keys(loose.p_world), _keys(tight.p_world))
    assert kept.sum() == len(tight) < len(loose)
    if mode == "spot":  # the cut is on sigma (largest axis)
        np.testing.assert_array_equal(kept, precise)
    else:  # on the sigma across the stripe, which is at most sigma: every precise point stays
        assert np.all(kept[precise]) and precise.any()
    assert f"{len(loose) - len(tight)} left out with error bound above {round(limit_mm, 4):g} mm" in text


def _keys(p_world):
    """One hashable key per point (its coordinates' bytes) to compare clouds written by two runs."""
    return np.ascontiguousarray(p_world, dtype=np.float64).view(np.dtype((np.void, 24))).ravel()
