"""The reflectance-step model: a printed edge under a clipped colour stripe, with exact truth."""

import numpy as np
import pytest
from scipy.special import fdtri, ndtr

from scanrig.laser import colour_fit
from scanrig.laser.colour_fit import fit_clipped
from scanrig.laser.colour_frames import ColourFrames
from scanrig.laser.reflectance import EDGE_WIDTH_PX, PARAMS, STEP_LEVEL, step_is_significant, step_start, with_step

from .synth import integrated, quantize

#: The rendered frame: paper's RGB level, the laser's peak on paper in red (6 × full scale) and its
#: crosstalk into green and blue, the beam's width, ink's reflectance relative to paper, the noise.
PAPER_RGB = np.array([164.0, 166.0, 153.0])
LASER_RGB = 6.0 * 255.0 * np.array([1.0, 0.07, 0.05])
BEAM_SIGMA_PX, INK, NOISE_DN = 1.2, 0.07, 2.0
#: Red clips here (the frame's saturation less a margin), DN.
CLIP_DN = 250.0
#: Rows with paper only (they set the frame's usual misfit), then rows with an ink edge this far
#: right of the beam (px): the plain colour model, one background per channel, converges away from
#: the beam there.
CLEAN_ROWS, EDGE_OFFSET_PX = 24, 2.5
#: Largest error accepted, in units of the reported σ.
Z_MAX = 3.5


def _frame(rng, edge_rows: int):
    """A vertical stripe at column 30.3 + 0.05 · row; on the last ``edge_rows`` rows ink from
    ``EDGE_OFFSET_PX`` right of the beam (the model's blurred step, ``EDGE_WIDTH_PX``), multiplying
    ambient light and laser alike. Returns the frame and each row's true centre and edge."""
    rows = CLEAN_ROWS + edge_rows
    x = np.arange(64, dtype=float)
    centre = 30.3 + 0.05 * np.arange(rows)
    edge = np.where(np.arange(rows) >= CLEAN_ROWS, centre + EDGE_OFFSET_PX, np.inf)
    rho = np.exp(np.log(INK) * ndtr((x[None, :] - edge[:, None]) / EDGE_WIDTH_PX))  # (rows, W)
    beam = integrated(x[None, :], centre[:, None], BEAM_SIGMA_PX)
    light = rho[:, :, None] * (PAPER_RGB + beam[:, :, None] * LASER_RGB)
    image = quantize(light + rng.normal(0.0, NOISE_DN, light.shape))
    return ColourFrames(image, None, 0, np.full(3, CLIP_DN)), centre


def _fit(colour: ColourFrames):
    """``fit_clipped`` on every row, each seeded at the middle of its clipped red run; centres
    (NaN where dropped) and σ per row."""
    red = colour.image[:, :, 0] >= CLIP_DN
    cols = np.arange(red.shape[1])
    first = np.where(red, cols, red.shape[1]).min(axis=1)
    last = np.where(red, cols, -1).max(axis=1)
    line = np.arange(red.shape[0])
    pos = (first + last) // 2
    run_half = (last - first) // 2
    fit = fit_clipped(colour, True, line, pos, 9 + int(run_half.max()), 2.0 + run_half / 2.0)
    centre, sigma = np.full(line.size, np.nan), np.full(line.size, np.nan)
    centre[fit["index"]], sigma[fit["index"]] = fit["centre"], np.sqrt(fit["var"])
    return centre, sigma


def test_a_printed_edge_beside_a_clipped_stripe_is_fitted_as_a_step(monkeypatch):
    colour, truth = _frame(np.random.default_rng(3), edge_rows=8)
    centre, sigma = _fit(colour)
    edge = slice(CLEAN_ROWS, None)
    err = centre - truth
    # within 3.5 σ on every row (a Gaussian error passes with probability 0.9995 per row)
    assert np.all(np.abs(err) <= Z_MAX * sigma)
    assert np.all(sigma[edge] < 0.2)
    with monkeypatch.context() as m:  # the plain colour model alone
        m.setattr(colour_fit, "_refit_with_step", lambda *args: None)
        plain, plain_sigma = _fit(colour)
    np.testing.assert_array_equal(plain[:CLEAN_ROWS], centre[:CLEAN_ROWS])  # untouched where clean
    np.testing.assert_array_equal(plain_sigma[:CLEAN_ROWS], sigma[:CLEAN_ROWS])
    # the plain model is off by more than 0.5 px, or converged so far from the seed that it is dropped
    assert np.all((np.abs(plain - truth)[edge] > 0.5) | np.isnan(plain[edge]))


def test_the_step_model_jacobian_is_its_derivative():
    rng = np.random.default_rng(1)
    x = np.arange(-6, 7, dtype=float)
    noise = np.array([2.0, 3.0, 2.5])
    model = with_step(colour_fit._model_1d(x, noise), x, 3)
    n = 4
    p = np.vstack([rng.uniform(-1, 1, n), rng.uniform(0.8, 2.0, n), rng.uniform(50, 200, (3, n)),
                   rng.uniform(10, 150, (3, n)), rng.uniform(-2.5, 2.5, n), rng.uniform(-3, 3, n)])
    _, jac = model(p)
    step = 1e-6 * np.maximum(np.abs(p), 1.0)
    for k in range(p.shape[0]):
        hi, lo = p.copy(), p.copy()
        hi[k] += step[k]
        lo[k] -= step[k]
        numeric = (model(hi)[0] - model(lo)[0]) / (2 * step[k])
        # central differences: error O(step²) times the third derivative, far below 1e-5 of the scale
        np.testing.assert_allclose(jac[k], numeric, rtol=1e-5, atol=1e-5 * np.abs(numeric).max())


def test_the_step_starts_at_the_split_between_the_two_levels():
    x = np.arange(-8, 9, dtype=float)
    mu = np.broadcast_to(np.array([100.0, 120.0, 90.0]), (1, x.size, 3))
    right = x > 2.0  # the step between pixels 2 and 3: the data's ratio to mu is 1, then 0.2
    y = mu * np.where(right, 0.2, 1.0)[None, :, None]
    start = step_start(y, mu, np.ones(y.shape, bool), np.array([2.0, 2.0, 2.0]), x)
    np.testing.assert_allclose(start[0], [0.0, np.log(0.2), 2.5], atol=1e-12)


@pytest.mark.parametrize("above", [False, True])
def test_the_step_is_kept_above_the_f_quantile(above):
    dof = np.array([40])
    chi2_step = np.array([40.0])  # residual variance 1
    f = fdtri(len(PARAMS), 40, STEP_LEVEL) * (1.01 if above else 0.99)
    assert step_is_significant(chi2_step + len(PARAMS) * f, chi2_step, dof)[0] == above
