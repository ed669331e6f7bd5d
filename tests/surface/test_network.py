"""Batched height-field networks."""

import pytest
import torch

from scanrig.errors import InputError
from scanrig.surface.network import HeightFieldNets


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
