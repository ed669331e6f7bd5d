"""Batched height-field networks, and charts of different sizes fitted in groups."""

import numpy as np
import pytest
import torch

from scanrig.errors import InputError
from scanrig.surface.network import HeightFieldNets
from scanrig.surface.robust_fit import FitSettings, fit_charts_by_size


@pytest.mark.parametrize("architecture, depth", [("ridge", 1), ("mlp", 2)])
def test_copies_are_independent_and_output_layer_is_linear_in_features(architecture, depth):
    gen = torch.Generator().manual_seed(0)
    nets = HeightFieldNets(3, hidden=5, depth=depth, architecture=architecture, generator=gen)
    uv = torch.rand(3, 7, 2, generator=gen)
    z = nets(uv)
    assert z.shape == (3, 7)
    coef = torch.randn(3, 6, generator=gen)
    nets.set_output(coef)
    expected = torch.bmm(nets.features(uv), coef[..., None])[..., 0]
    torch.testing.assert_close(nets(uv), expected)
    # changing copy 0's input does not change copies 1 and 2
    uv2 = uv.clone()
    uv2[0] += 1.0
    torch.testing.assert_close(nets(uv2)[1:], nets(uv)[1:])


def test_ridge_network_has_one_hidden_layer():
    with pytest.raises(InputError, match="one hidden layer"):
        HeightFieldNets(1, hidden=4, depth=2, architecture="ridge", generator=torch.Generator())
    with pytest.raises(InputError, match="architecture"):
        HeightFieldNets(1, hidden=4, depth=1, architecture="siren", generator=torch.Generator())


def test_charts_of_different_sizes_are_fitted_in_groups_and_returned_in_input_order():
    # three planes of different sizes and offsets: each chart's fit must follow its own data
    rng = np.random.default_rng(5)
    sizes, offsets = [40, 400, 90], [2.0, -1.0, 0.5]
    uv = [rng.uniform(-1, 1, (n, 2)) for n in sizes]
    z = [o + 0.3 * p[:, 0] + rng.normal(0, 0.01, len(p)) for o, p in zip(offsets, uv)]
    settings = FitSettings(hidden=6, depth=1, epochs=60, robust_epochs=60, update_every=30,
                           start_epochs=20, n_boot=50)
    fits = fit_charts_by_size(uv, z, settings=settings, rng=np.random.default_rng(0), max_padding=1.25)
    padded = np.zeros((3, max(sizes), 2))
    for c, p in enumerate(uv):
        padded[c, :len(p)] = p
    predicted = fits.predict(padded)
    for c, n in enumerate(sizes):
        assert np.sqrt(np.mean((fits.z_fit[c, :n] - z[c]) ** 2)) < 0.05
        np.testing.assert_allclose(predicted[c, :n], fits.z_fit[c, :n], atol=1e-5)
    assert fits.sigma.shape == (3,) and all(h["sigma_upper"].shape == (3,) for h in fits.history)
