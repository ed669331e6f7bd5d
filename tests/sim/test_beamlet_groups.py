"""Overlapping secondary beamlets merge into fewer that render the same light; others stay as they are."""

from __future__ import annotations

import numpy as np
import pytest

from scanrig.sim.beamlet_groups import merge_overlapping
from scanrig.sim.laser import FOOTPRINT_RADII, GaussianBeams

WAIST_M = 5e-4          # 1/e² radius at the landing (waist there): sigma = 0.25 mm
RAYLEIGH_M = 1.0


def _line(spacing_m: float, m: int = 200) -> dict:
    """``m`` parallel beamlets falling straight down onto z = 0, landing ``spacing_m`` apart along x,
    waist at the landing, powers varying smoothly along the line."""
    x = (np.arange(m) - m / 2) * spacing_m
    landing = np.column_stack([x, np.zeros(m), np.zeros(m)])
    direction = np.tile([0.0, 0.0, -1.0], (m, 1))
    return {"origin": landing + [0.0, 0.0, 0.2], "direction": direction, "waist_m": np.full(m, WAIST_M),
            "focus_m": np.full(m, 0.2), "rayleigh_m": np.full(m, RAYLEIGH_M),
            "power_W": 1e-4 * (1.5 + np.sin(x / (40 * WAIST_M))), "emitter_normal": np.tile([0.0, 0.0, 1.0], (m, 1)),
            "landing": landing, "reach_m": np.full(m, FOOTPRINT_RADII * WAIST_M)}


def _merge(beamlets: dict, fan_index=None, emitter_obj=None, landing_obj=None) -> dict:
    m = len(beamlets["power_W"])
    # each lands at its waist
    return merge_overlapping(beamlets, beamlets["waist_m"], np.arange(m) if fan_index is None else fan_index,
                             np.zeros(m, int) if emitter_obj is None else emitter_obj,
                             np.zeros(m, int) if landing_obj is None else landing_obj)


def test_dense_beamlets_merge_into_fewer_with_the_same_power():
    dense = _line(0.2 * WAIST_M / 2)            # a fifth of sigma apart
    merged = _merge(dense)
    assert 4 <= len(dense["power_W"]) / len(merged["power_W"]) <= 6
    assert merged["power_W"].sum() == pytest.approx(dense["power_W"].sum(), rel=1e-12)
    np.testing.assert_allclose(np.linalg.norm(merged["direction"], axis=1), 1.0, rtol=1e-12)


def _light_near_the_line(dense: dict, merged: dict) -> tuple[np.ndarray, np.ndarray]:
    """Irradiance of the dense and the merged beamlets at points on z = 0 within 3 sigma of the
    landing line, away from its ends."""
    rng = np.random.default_rng(3)
    n = 4000
    inner = 0.4 * np.ptp(dense["landing"][:, 0])
    x = np.column_stack([rng.uniform(-inner, inner, n), rng.uniform(-1.5, 1.5, n) * WAIST_M, np.zeros(n)])
    return GaussianBeams(**dense).evaluate(x)[0], GaussianBeams(**merged).evaluate(x)[0]


def test_evenly_merged_beamlets_light_the_landing_line_as_the_dense_ones_do():
    # a quarter sigma apart (exact in binary): groups of exactly four, one sigma apart. Gaussians
    # sampled every sigma ripple by 2 exp(-2 pi²) ~ 5e-9 of their sum; the powers' slow variation
    # along the line (period 125 mm) is averaged to second order over a group.
    dense = _line(0.25 * WAIST_M / 2)
    merged = _merge(dense)
    np.testing.assert_allclose(merged["power_W"], dense["power_W"].reshape(-1, 4).sum(axis=1), rtol=1e-12)
    want, got = _light_near_the_line(dense, merged)
    np.testing.assert_allclose(got, want, rtol=1e-4)


def test_unevenly_merged_beamlets_light_the_landing_line_within_the_midpoint_rules_error():
    # 0.23 sigma apart: groups of four or five members. A group of length L taken as one beamlet at
    # its centroid misses its share by the midpoint rule's L³ G''/24, which no longer cancels
    # between unequal neighbours: with L <= sigma at most (1/24)/sqrt(2 pi) ~ 1.7 % of the
    # line's peak light.
    dense = _line(0.23 * WAIST_M / 2)
    merged = _merge(dense)
    assert 4 < len(dense["power_W"]) / len(merged["power_W"]) < 5
    want, got = _light_near_the_line(dense, merged)
    assert np.abs(got - want).max() <= 0.017 * want.max()


def test_beamlets_a_sigma_or_more_apart_are_left_as_they_are():
    sparse = _line(1.05 * WAIST_M / 2, m=50)
    merged = _merge(sparse)
    for name, value in sparse.items():
        np.testing.assert_array_equal(merged[name], value)


@pytest.mark.parametrize("cut", ["fan_index", "emitter_obj", "landing_obj"])
def test_no_group_spans_a_gap_in_the_fan_or_two_objects(cut):
    dense = _line(0.2 * WAIST_M / 2, m=40)
    labels = {"fan_index": np.arange(40), "emitter_obj": np.zeros(40, int), "landing_obj": np.zeros(40, int)}
    labels[cut] = labels[cut] + (np.arange(40) % 2 if cut != "fan_index" else np.arange(40))   # every step cut
    merged = _merge(dense, **labels)
    np.testing.assert_array_equal(merged["power_W"], dense["power_W"])


def test_a_merged_beamlets_reach_covers_its_members():
    dense = _line(0.2 * WAIST_M / 2, m=60)
    merged = _merge(dense)
    gap = np.linalg.norm(dense["landing"][:, None] - merged["landing"][None], axis=2)   # (member, merged)
    covered = gap + dense["reach_m"][:, None] <= merged["reach_m"][None] + 1e-15
    # every member's disc of reach lies within the reach of the merged beamlet that took it
    assert covered.any(axis=1).all()


def test_beamlets_that_leave_in_directions_further_apart_than_their_divergence_stay_apart():
    # landing close together but crossing there (a caustic): each keeps its own direction
    dense = _line(0.2 * WAIST_M / 2, m=40)
    divergence_rad = WAIST_M / RAYLEIGH_M
    tilt = 2.0 * divergence_rad * np.arange(40)
    dense["direction"] = np.column_stack([np.sin(tilt), np.zeros(40), -np.cos(tilt)])
    merged = _merge(dense)
    np.testing.assert_array_equal(merged["power_W"], dense["power_W"])
