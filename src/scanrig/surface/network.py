"""A batch of independent height-field networks ``z = f(u, v)``, one per (chart, fold) copy.

Every copy has the same architecture and its own weights; all copies are evaluated with one
batched matrix product, so fitting many charts costs one forward pass, not a Python loop.

Architectures
-------------
``"ridge"``
    One hidden layer of ridge units ``s(a u + b v + c)`` with the logistic sigmoid ``s``, summed
    with output weights: the network of the source method (Chen & Jain's "nonlinear cascade of
    affine transformations" with one hidden layer).
``"mlp"``
    ``depth`` hidden layers of ``tanh`` units (our choice for the default: deeper networks fit
    creases and steps with fewer units).

Inputs and outputs are in the chart's normalised coordinates (about [-1, 1]); the caller scales.
"""

from __future__ import annotations

import math

import torch

from scanrig.errors import InputError

ARCHITECTURES = ("ridge", "mlp")


class HeightFieldNets(torch.nn.Module):
    """``n_models`` independent networks mapping ``(u, v)`` to ``z``.

    Parameters
    ----------
    n_models : int
        Number of independent copies.
    hidden : int
        Units per hidden layer.
    depth : int
        Hidden layers (``"ridge"`` requires 1).
    architecture : {"ridge", "mlp"}
        See the module docstring.
    generator : torch.Generator
        Seeds the initial weights.
    first_layer_scale : float
        Standard deviation of the first-layer weights; larger values start with sharper ridges.
    """

    def __init__(self, n_models: int, *, hidden: int, depth: int, architecture: str,
                 generator: torch.Generator, first_layer_scale: float = 3.0):
        super().__init__()
        if architecture not in ARCHITECTURES:
            raise InputError(f"architecture must be one of {ARCHITECTURES}, got {architecture!r}")
        if architecture == "ridge" and depth != 1:
            raise InputError(f"the 'ridge' network has one hidden layer, got depth={depth}")
        if hidden < 1 or depth < 1:
            raise InputError(f"hidden and depth must be >= 1, got {hidden}, {depth}")
        self.architecture = architecture
        self.activation = torch.sigmoid if architecture == "ridge" else torch.tanh
        widths = [2] + [hidden] * depth + [1]
        weights, biases = [], []
        for i, (w_in, w_out) in enumerate(zip(widths[:-1], widths[1:])):
            std = first_layer_scale if i == 0 else 1.0 / math.sqrt(w_in)
            weights.append(torch.nn.Parameter(
                std * torch.randn(n_models, w_in, w_out, generator=generator)))
            bias_std = first_layer_scale if i == 0 else 0.0
            biases.append(torch.nn.Parameter(
                bias_std * torch.randn(n_models, 1, w_out, generator=generator)))
        self.weights = torch.nn.ParameterList(weights)
        self.biases = torch.nn.ParameterList(biases)

    @classmethod
    def concatenate(cls, parts: list[HeightFieldNets], order: torch.Tensor) -> HeightFieldNets:
        """One batch holding the copies of several batches of the same architecture.

        Parameters
        ----------
        parts : list of HeightFieldNets
            Same ``architecture``, ``hidden`` and ``depth``.
        order : (n_models,) int tensor
            Copy ``i`` of the result is copy ``order[i]`` of the parts' copies laid end to end.
        """
        first = parts[0]
        out = cls(1, hidden=first.weights[0].shape[-1], depth=len(first.weights) - 1,
                  architecture=first.architecture, generator=torch.Generator())
        with torch.no_grad():
            for mine, theirs in ((out.weights, [p.weights for p in parts]),
                                 (out.biases, [p.biases for p in parts])):
                for i in range(len(mine)):
                    mine[i] = torch.nn.Parameter(torch.cat([t[i] for t in theirs])[order])
        return out

    def subset(self, copies: torch.Tensor) -> HeightFieldNets:
        """The copies ``copies`` (int tensor) as a batch of their own, with copied weights."""
        return HeightFieldNets.concatenate([self], copies)

    @torch.no_grad()
    def assign(self, copies: torch.Tensor, part: HeightFieldNets) -> None:
        """Set the copies ``copies`` (int tensor) to the copies of ``part``, in order."""
        for mine, theirs in ((self.weights, part.weights), (self.biases, part.biases)):
            for p, q in zip(mine, theirs):
                p[copies] = q

    def features(self, uv: torch.Tensor, copies: torch.Tensor | None = None) -> torch.Tensor:
        """Activations of the last hidden layer, unit-major.

        The points lie along the last, contiguous axis: the products of every layer and their
        gradients then run over long contiguous rows, and the normal equations of the output
        layer need no transposed copy (an epoch took 3-20 % less time than point-major
        activations, torch 2.13 on 2 CPU cores, measured).

        Parameters
        ----------
        uv : (n_models, n, 2) tensor, or (V, n, 2) with ``copies``
            Normalised chart coordinates.
        copies : (V,) int tensor, optional
            Which copy's weights evaluate each batch entry (several entries may share a copy:
            its points split in blocks of equal size); default: entry i is copy i.

        Returns
        -------
        (n_models or V, hidden, n) tensor
            The output layer is affine in these: ``z = w_out . features + b_out``.
        """
        h = uv.transpose(1, 2)
        # the hidden layers: every layer but the output's (a slice of a ParameterList builds a
        # new module at every call)
        for w, b in list(zip(self.weights, self.biases))[:-1]:
            if copies is not None:
                w, b = w[copies], b[copies]
            h = self.activation(torch.baddbmm(b.transpose(1, 2), w.transpose(1, 2), h))
        return h

    def hidden_parameters(self) -> list[torch.nn.Parameter]:
        """Weights and biases of the hidden layers (the output layer is solved, not descended)."""
        return list(self.weights[:-1]) + list(self.biases[:-1])

    @torch.no_grad()
    def set_output(self, coef: torch.Tensor) -> None:
        """Set the linear output layer from ``(n_models, hidden + 1)`` coefficients (last = bias)."""
        self.weights[-1].copy_(coef[:, :-1, None])
        self.biases[-1].copy_(coef[:, None, -1:])

    def forward(self, uv: torch.Tensor) -> torch.Tensor:
        """Heights of every copy at its own inputs.

        Parameters
        ----------
        uv : (n_models, n, 2) tensor
            As in :meth:`features`.

        Returns
        -------
        (n_models, n) tensor
            Normalised heights.
        """
        h = self.features(uv)
        return torch.baddbmm(self.biases[-1], self.weights[-1].transpose(1, 2), h)[:, 0]
