"""Secondary beamlets merged where they overlap so much that one beamlet renders their light.

A stripe's fan is cast as :data:`~scanrig.sim.laser.N_FAN_SAMPLES` rays and every shiny hit sends
out one Gaussian beamlet. Where a reflection spreads the light little, neighbouring beamlets land a
fraction of their width apart (a quarter of their σ on some sheets of the default scene), and a
point of the reflected stripe sums the light of dozens of them: its cost grows with that count,
the light it sums hardly changes.

A run of neighbouring beamlets (consecutive fan samples, leaving one object and landing on one)
that land within ``σ`` of each other (``σ = w / 2``, ``w`` the 1/e² radius where they land) and
leave in directions closer than their divergence is therefore cut into groups spanning
:data:`GROUP_SPAN_SIGMA` σ along their landings, and each group becomes one beamlet with the
group's power, at the power-weighted mean of its members' parameters. Gaussians of width σ
sampled every ``D <= σ`` along a line sum to the continuous line's light within a ripple of
``2 exp(−2 π² σ² / D²) <= 5e-9``; groups of unequal length add the midpoint rule's error, at most
about (1/24)/√(2π) ≈ 1.7 % of the line's peak. Beamlets that already land more than σ apart (a
reflection that spreads its light) are left as they are. ``docs/simulator.md`` gives the effect on
rendered frames.
"""

from __future__ import annotations

import numpy as np

#: Length along the landings of one merged group, in units of the members' σ at landing.
GROUP_SPAN_SIGMA = 1.0
#: Fields averaged as points or scalars (power-weighted), and as unit vectors (renormalised).
_MEANS = ("origin", "waist_m", "focus_m", "rayleigh_m", "landing")
_UNIT_MEANS = ("direction", "emitter_normal")


def merge_overlapping(beamlets: dict, radius_m: np.ndarray, fan_index: np.ndarray, emitter_obj: np.ndarray,
                      landing_obj: np.ndarray) -> dict:
    """Merge the groups of overlapping beamlets of one stripe (see the module docstring).

    Parameters
    ----------
    beamlets : dict
        :class:`~scanrig.sim.laser.GaussianBeams` fields of ``M`` landed beamlets in fan order:
        ``origin, direction, emitter_normal, landing`` (M, 3); ``waist_m, focus_m, rayleigh_m,
        power_W, reach_m`` (M,).
    radius_m : ndarray of shape (M,)
        Each beamlet's 1/e² radius where it lands, metres.
    fan_index : ndarray of shape (M,), int
        Each beamlet's fan sample, increasing: beamlets are neighbours when theirs differ by one.
    emitter_obj, landing_obj : ndarray of shape (M,), int
        The objects each beamlet leaves and lands on: a group never spans two.

    Returns
    -------
    dict
        The same fields for the merged beamlets, in fan order. Power is conserved; each merged
        beamlet's reach covers its members' (their reach plus their distance from its landing).
    """
    landing = beamlets["landing"]
    m = len(landing)
    if m < 2:
        return beamlets
    sigma_m = 0.5 * radius_m
    step = np.linalg.norm(np.diff(landing, axis=0), axis=1) / np.minimum(sigma_m[1:], sigma_m[:-1])   # (M-1,)
    turn = np.linalg.norm(np.diff(beamlets["direction"], axis=0), axis=1)   # angle between neighbours, rad
    spread = beamlets["waist_m"] / beamlets["rayleigh_m"]               # far-field half-angle, rad
    apart = ((np.diff(fan_index) != 1) | (np.diff(emitter_obj) != 0) | (np.diff(landing_obj) != 0)
             | ~(step <= 1.0) | ~(turn <= np.minimum(spread[1:], spread[:-1])))
    # arc length along the landings in σ, counted from each run's first beamlet
    arc = np.concatenate([[0.0], np.cumsum(np.where(apart, 0.0, step))])
    run_start = np.maximum.accumulate(np.where(np.concatenate([[True], apart]), np.arange(m), 0))
    # an arc of a whole number of spans up to rounding opens the next group: even steps, even groups
    cell = np.floor((arc - arc[run_start]) / GROUP_SPAN_SIGMA + 1e-9)
    starts = np.flatnonzero(np.concatenate([[True], apart | (np.diff(cell) != 0)]))
    if len(starts) == m:
        return beamlets
    size = np.diff(np.append(starts, m))
    power = beamlets["power_W"]
    group_power = np.add.reduceat(power, starts)
    weight = power / np.repeat(group_power, size)

    def weighted_mean(values):
        return np.add.reduceat(values * (weight if values.ndim == 1 else weight[:, None]), starts, axis=0)

    merged = {"power_W": group_power}
    merged.update({name: weighted_mean(beamlets[name]) for name in _MEANS})
    for name in _UNIT_MEANS:
        mean = weighted_mean(beamlets[name])
        merged[name] = mean / np.linalg.norm(mean, axis=1, keepdims=True)
    off_m = np.linalg.norm(landing - np.repeat(merged["landing"], size, axis=0), axis=1)
    merged["reach_m"] = np.maximum.reduceat(beamlets["reach_m"] + off_m, starts)
    return merged
